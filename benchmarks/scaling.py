"""Perception throughput with 1 and 2 workers sharing one stream (rendezvous hashing over
their liveliness tokens), on this machine: a router in this process, the workers as processes,
a burst of 640×480 tabletop_clutter frames published as fast as they are taken (a bounded
queue per worker, so nothing is dropped), observations counted until all are back. With two
workers each gets half the cores for its numba kernels, as ``avs up --scale`` does (one
worker alone uses them all).

Last line: perception_fps_1=<x> perception_fps_2=<y>
Target (issue 8): y ≥ 1.6·x on the 2-core machine.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from avs.launcher import threads_per_instance  # noqa: E402
from avs.router import open_router  # noqa: E402
from benchmarks._loopback import client_config, free_endpoint, stop  # noqa: E402
from schemas import Keys, encode  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402


def frame_payloads(n: int) -> list[bytes]:
    world = World("tabletop_clutter", ARMAR6)
    renderer = CameraRenderer(world.model, 640, 480)
    T, stamp = capture.snapshot(world, renderer, "head_rgbd")
    frame = capture.frame(world, renderer, "head_rgbd", T, stamp, 0, np.random.default_rng(0))
    renderer.close()
    return [encode(frame.model_copy(update={"seq": i})) for i in range(n)]


def run(endpoint: str, workers: int, payloads: list[bytes]) -> float:
    keys = Keys()
    env = dict(os.environ, AVS_MODE="client", AVS_CONNECT=endpoint, AVS_MULTICAST="false",
               AVS_PERCEPTION_QUEUE=str(len(payloads)), AVS_LOG_LEVEL="WARNING",
               PYTHONPATH=str(ROOT))  # fmt: skip
    if workers > 1:  # as avs up --scale does: the cores shared out between the workers
        env["NUMBA_NUM_THREADS"] = str(threads_per_instance(workers))
    names = [f"bench-{workers}-{i}" for i in range(workers)]
    procs = [subprocess.Popen([sys.executable, "-m", "services.perception", "--instance", n],
                              env=env) for n in names]  # fmt: skip
    config = client_config(endpoint)
    done = [0]
    lock = threading.Lock()
    all_back = threading.Event()

    def on_observation(_sample) -> None:
        with lock:
            done[0] += 1
            if done[0] == len(payloads):
                all_back.set()

    try:
        with zenoh.open(config) as session:
            sub = session.declare_subscriber(keys.observation(), on_observation)
            wanted = {keys.alive("perception", n) for n in names}
            deadline = time.monotonic() + 120
            while time.monotonic() < deadline:
                live = {str(r.ok.key_expr) for r in session.liveliness().get(keys.alive()) if r.ok}
                if wanted <= live:
                    break
                time.sleep(0.2)
            time.sleep(1.0)  # every worker has seen the others
            block = zenoh.CongestionControl.BLOCK
            pub = session.declare_publisher(keys.rgbd("head_rgbd"), congestion_control=block)
            t0 = time.perf_counter()
            for p in payloads:
                pub.put(p)
            if not all_back.wait(600):
                raise RuntimeError(f"only {done[0]} of {len(payloads)} observations came back")
            elapsed = time.perf_counter() - t0
            sub.undeclare()
    finally:
        stop(procs)
    return len(payloads) / elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=60)
    args = parser.parse_args()
    payloads = frame_payloads(args.frames)
    endpoint = free_endpoint()
    router = open_router([endpoint])
    try:
        fps = {}
        for n in (1, 2):
            fps[n] = run(endpoint, n, payloads)
            print(f"{n} worker(s): {fps[n]:.1f} frames/s over {args.frames} frames", flush=True)
    finally:
        router.close()
    print(f"ratio {fps[2] / fps[1]:.2f} (target ≥ 1.6 with 2 cores)")
    print(f"perception_fps_1={fps[1]:.1f} perception_fps_2={fps[2]:.1f}")


if __name__ == "__main__":
    main()
