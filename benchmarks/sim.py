"""The sim on this machine: RGB-D frames/s at 640×480 and 320×240, and the IMU samples/s a
subscriber receives while frames render. The sim runs as a process in real time (renders as
fast as it can, up to 60 fps) on the tabletop_clutter scene; a subscriber in this process
counts what arrives over Zenoh on loopback.

Last line: rgbd_fps_640=<x> rgbd_fps_320=<y> imu_hz=<z>
Targets (issue 3): ≥ 15 frames/s at 640×480, IMU ≥ 500 Hz delivered.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from avs.router import open_router  # noqa: E402
from benchmarks._loopback import client_config, free_endpoint, stop  # noqa: E402
from schemas import Keys  # noqa: E402


def run(endpoint: str, width: int, height: int, seconds: float) -> tuple[float, float]:
    keys = Keys()
    env = dict(
        os.environ,
        AVS_MODE="client",
        AVS_CONNECT=endpoint,
        AVS_MULTICAST="false",
        PYTHONPATH=str(ROOT),
        MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
        AVS_LOG_LEVEL="WARNING",
    )
    sim = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.sim",
            "--scene",
            "tabletop_clutter",
            "--fps",
            "60",
            "--width",
            str(width),
            "--height",
            str(height),
        ],
        env=env,
    )
    config = client_config(endpoint)
    counts = {"frames": 0, "imu": 0}
    lock = threading.Lock()

    def count(kind: str):
        def on_sample(_sample) -> None:
            with lock:
                counts[kind] += 1

        return on_sample

    with zenoh.open(config) as session:
        session.declare_subscriber(keys.rgbd("*"), count("frames"))
        session.declare_subscriber(keys.imu(), count("imu"))
        deadline = time.monotonic() + 60
        while counts["frames"] < 3 and time.monotonic() < deadline:  # warmed up
            time.sleep(0.05)
        with lock:
            start = dict(counts)
        t0 = time.monotonic()
        for i in range(int(seconds)):
            time.sleep(1.0)
            print(
                f"\r  {width}×{height}: {i + 1}/{int(seconds)} s",
                end="",
                file=sys.stderr,
                flush=True,
            )
        elapsed = time.monotonic() - t0
        with lock:
            frames = (counts["frames"] - start["frames"]) / elapsed
            imu = (counts["imu"] - start["imu"]) / elapsed
    print(file=sys.stderr)
    stop([sim])
    return frames, imu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0, help="measuring time per size")
    args = parser.parse_args()
    endpoint = free_endpoint()
    router = open_router([endpoint])
    try:
        fps_640, imu_640 = run(endpoint, 640, 480, args.seconds)
        print(f"640×480: {fps_640:.1f} RGB-D frames/s, IMU {imu_640:.0f} samples/s delivered")
        fps_320, imu_320 = run(endpoint, 320, 240, args.seconds)
        print(f"320×240: {fps_320:.1f} RGB-D frames/s, IMU {imu_320:.0f} samples/s delivered")
    finally:
        router.close()
    print(f"rgbd_fps_640={fps_640:.1f} rgbd_fps_320={fps_320:.1f} imu_hz={imu_640:.0f}")


if __name__ == "__main__":
    main()
