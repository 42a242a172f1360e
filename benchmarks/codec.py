"""One 640×480 RGB-D frame through our codec and through pickle protocol 5 of the same numpy
arrays; then its one-way latency between two processes over Zenoh on loopback (publisher →
router → subscriber, the topology of `avs up`).

The peer: a dict of the frame's fields (rgb and depth as the same numpy arrays, the pose as
an array, the scalars) pickled with protocol 5 — in-band (one bytes object, the arrays copied
into it) and out-of-band (``buffer_callback``: the arrays stay where they are as
``PickleBuffer`` views, ``loads(..., buffers=...)`` rebuilds them without a copy; no single
payload comes out, so this is a lower bound of what any pickle transport costs). Pickle
validates nothing on loads; ours decodes into a validated ``RgbdFrame``.

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


def pickle_fields(frame: RgbdFrame) -> dict:
    """The frame as pickle's peer sends it: the same numpy arrays, scalars as they are."""
    K = frame.intrinsics
    return {
        "seq": frame.seq,
        "stamp": frame.stamp,
        "camera": frame.camera,
        "intrinsics": (K.width, K.height, K.fx, K.fy, K.cx, K.cy),
        "rgb": frame.rgb,
        "depth": frame.depth,
        "T_world_camera": np.asarray(frame.T_world_camera),
        "depth_min": frame.depth_min,
        "depth_max": frame.depth_max,
    }


def codec_times(repeats: int) -> dict[str, tuple[float, float, float, int]]:
    """Median ms of encode, of decode and of both in a row (the round trip), and the bytes
    it gives, per codec."""
    frame = make_frame()
    fields = pickle_fields(frame)
    wire = encode(frame)
    in_band = pickle.dumps(fields, protocol=5)
    buffers: list[pickle.PickleBuffer] = []
    oob = pickle.dumps(fields, protocol=5, buffer_callback=buffers.append)
    assert np.array_equal(decode(wire, RgbdFrame).depth, frame.depth)
    assert np.array_equal(pickle.loads(in_band)["rgb"], frame.rgb)
    assert np.array_equal(pickle.loads(oob, buffers=buffers)["depth"], frame.depth)

    def oob_encode():
        bufs: list[pickle.PickleBuffer] = []
        return pickle.dumps(fields, protocol=5, buffer_callback=bufs.append), bufs

    def oob_round_trip():
        data, bufs = oob_encode()
        return pickle.loads(data, buffers=bufs)

    return {
        "ours": (
            median_ms(lambda: encode(frame), repeats),
            median_ms(lambda: decode(wire, RgbdFrame), repeats),
            median_ms(lambda: decode(encode(frame), RgbdFrame), repeats),
            len(wire),
        ),
        "pickle5 in-band": (
            median_ms(lambda: pickle.dumps(fields, protocol=5), repeats),
            median_ms(lambda: pickle.loads(in_band), repeats),
            median_ms(lambda: pickle.loads(pickle.dumps(fields, protocol=5)), repeats),
            len(in_band),
        ),
        "pickle5 out-of-band": (
            median_ms(oob_encode, repeats),
            median_ms(lambda: pickle.loads(oob, buffers=buffers), repeats),
            median_ms(oob_round_trip, repeats),
            len(oob) + sum(b.raw().nbytes for b in buffers),
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

    print("codec: one 640×480 RGB-D frame (rgb uint8 + depth float32), median ms")
    t = codec_times(args.repeats)
    ours = t["ours"][2]
    print(
        f"  {'':20s} {'encode':>8s} {'decode':>8s} {'round trip':>10s} {'frames/s':>9s} "
        f"{'÷ ours':>7s} {'bytes':>9s}"
    )
    for name, (enc, dec, both, size) in t.items():
        print(
            f"  {name:20s} {enc:8.3f} {dec:8.3f} {both:10.3f} {1e3 / both:9.1f} "
            f"{both / ours:6.2f}× {size:9d}"
        )
    print(f"latency: {args.n} frames at {args.rate:.0f} Hz, publisher → router → subscriber")
    lat = latency_ms(args.n, args.rate)
    p50, p99 = np.percentile(lat, 50), np.percentile(lat, 99)
    print(
        f"  received {lat.size}/{args.n}  p50 {p50:.2f} ms  p99 {p99:.2f} ms  max {lat.max():.2f}"
    )
    print(f"codec_fps={1e3 / ours:.0f} latency_p50_ms={p50:.2f} latency_p99_ms={p99:.2f}")


if __name__ == "__main__":
    main()
