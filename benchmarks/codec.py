"""One 640×480 RGB-D frame through our codec, pickle, and msgpack of nested lists; then its
one-way latency between two processes over Zenoh on loopback (publisher → router → subscriber,
the topology of `avs up`).

Last line: codec_fps=<ours> latency_p50_ms=<x> latency_p99_ms=<y>
Targets (issue 2): codec ≥ 200 frames/s, p50 ≤ 5 ms, p99 ≤ 15 ms.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import time
from pathlib import Path

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from schemas import CameraIntrinsics, Keys, RgbdFrame, decode, encode  # noqa: E402


def make_frame(seq: int = 0, stamp: float = 0.0) -> RgbdFrame:
    rng = np.random.default_rng(seq)
    return RgbdFrame(
        seq=seq,
        stamp=stamp,
        camera="head_rgbd",
        intrinsics=CameraIntrinsics.from_fov(640, 480, 45.0),
        rgb=rng.integers(0, 256, (480, 640, 3), dtype=np.uint8),
        depth=rng.uniform(0.35, 3.0, (480, 640)).astype(np.float32),
        T_world_camera=np.eye(4),
        depth_min=0.35,
        depth_max=3.0,
    )


def median_ms(fn, repeats: int) -> float:
    fn()  # warm up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def codec_times(repeats: int) -> dict[str, float]:
    frame = make_frame()
    as_lists = {"rgb": frame.rgb.tolist(), "depth": frame.depth.tolist()}
    return {
        "ours": median_ms(lambda: decode(encode(frame), RgbdFrame), repeats),
        "pickle": median_ms(lambda: pickle.loads(pickle.dumps(frame, protocol=5)), repeats),
        "msgpack_lists": median_ms(
            lambda: msgpack.unpackb(msgpack.packb(as_lists)), max(3, repeats // 40)
        ),
    }


# -- latency: router in this process, publisher and subscriber as two child processes ------------


def subscriber(n: int) -> None:
    from services.common import Node, ServiceSettings

    latencies: list[float] = []
    with Node("bench_sub", ServiceSettings.from_args([])) as node:

        def on_frame(frame: RgbdFrame) -> None:
            latencies.append(time.time() - frame.stamp)
            if len(latencies) == n:
                node.stop()

        node.subscribe(Keys().rgbd("head_rgbd"), RgbdFrame, on_frame)
        print("ready", flush=True)
        node.spin(120)
    print(json.dumps(latencies), flush=True)


def publisher(n: int, rate: float) -> None:
    from services.common import Node, ServiceSettings

    frames = [make_frame(i) for i in range(8)]
    with Node("bench_pub", ServiceSettings.from_args([])) as node:
        out = node.publisher(Keys().rgbd("head_rgbd"))
        deadline = time.monotonic() + 30
        while not out.matched and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(n):
            frame = frames[i % len(frames)].model_copy(update={"seq": i, "stamp": time.time()})
            out.put(frame)
            time.sleep(1 / rate)


def latency_ms(n: int, rate: float) -> np.ndarray:
    import socket

    from avs.router import open_router

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    router = open_router([endpoint])
    env = dict(os.environ, AVS_MODE="client", AVS_CONNECT=endpoint, AVS_MULTICAST="false")
    env["PYTHONPATH"] = str(ROOT)
    env["AVS_LOG_LEVEL"] = "WARNING"
    me = [sys.executable, __file__]
    sub = subprocess.Popen([*me, "--role", "sub", "-n", str(n)], env=env, stdout=subprocess.PIPE)
    assert sub.stdout.readline().strip() == b"ready"
    pub = subprocess.Popen([*me, "--role", "pub", "-n", str(n), "--rate", str(rate)], env=env)
    pub.wait()
    out, _ = sub.communicate(timeout=60)
    router.close()
    return np.array(json.loads(out)) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--role", choices=["bench", "sub", "pub"], default="bench")
    parser.add_argument("-n", type=int, default=300, help="frames for the latency run")
    parser.add_argument("--rate", type=float, default=30.0, help="frames/s of the latency run")
    parser.add_argument("--repeats", type=int, default=200, help="codec repetitions")
    args = parser.parse_args()
    if args.role == "sub":
        return subscriber(args.n)
    if args.role == "pub":
        return publisher(args.n, args.rate)

    print("codec: one 640×480 RGB-D frame (rgb uint8 + depth float32), encode + decode")
    t = codec_times(args.repeats)
    for name, ms in t.items():
        print(f"  {name:14s} {ms:9.3f} ms   {1e3 / ms:9.1f} frames/s   ×{ms / t['ours']:.1f}")
    print(f"latency: {args.n} frames at {args.rate:.0f} Hz, publisher → router → subscriber")
    lat = latency_ms(args.n, args.rate)
    p50, p99 = np.percentile(lat, 50), np.percentile(lat, 99)
    print(
        f"  received {lat.size}/{args.n}  p50 {p50:.2f} ms  p99 {p99:.2f} ms  max {lat.max():.2f}"
    )
    print(f"codec_fps={1e3 / t['ours']:.0f} latency_p50_ms={p50:.2f} latency_p99_ms={p99:.2f}")


if __name__ == "__main__":
    main()
