"""What the other threads of a service's process cost its frame step: the scene memory's two
compiled parts of a kitchen frame (the occupancy map's ``integrate`` and the registered cloud's
``add_frame``) timed alone, beside a busy compiled thread (a core taken, the GIL free: the
floor), and beside a busy Python thread (a core taken and the GIL held), at CPython's default
switch interval (5 ms) and at the one every AVS service sets (``ServiceSettings``'
``switch_interval_ms``, 0.5 ms).

Every call into compiled code that lets the GIL go, and every numba parallel region (which
takes the GIL before it starts its threads and again after they finish), waits until the
thread holding the GIL is made to give it up: up to a switch interval each time. A service's
node runs its frame step beside its network callbacks and other handlers (the scene memory's
fusion), all Python.

Frames: the kitchen's start view and a ±6° head pan of ``--frames`` frames (640×480, noise
on; rendered in a child process), every 2nd pixel each way, into the live stack's kitchen map
at 1 cm (``benchmarks/occupancy.py``'s inputs); medians over the pan and ``--repeats`` runs.

Last line: frame_ms=<alone> frame_busy_compiled_ms=<x> frame_busy_python_5ms=<x>
frame_busy_python_0_5ms=<x> gil_wait_ms_5ms=<busy Python − busy compiled, at 5 ms>
gil_wait_ms_0_5ms=<the same at 0.5 ms>
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._busy import busy_thread  # noqa: E402
from benchmarks.occupancy import frame_points, kitchen_case  # noqa: E402
from services.common.config import ServiceSettings  # noqa: E402
from services.scene_memory.cloud_merge import add_frame  # noqa: E402
from services.scene_memory.memory import MAX_CLOUD, MemoryConfig  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap  # noqa: E402


def kitchen(frames: int) -> tuple[list, np.ndarray, np.ndarray]:
    """The kitchen pan's (points, eye) and its map's bounds."""
    _, _, views, lo, hi = kitchen_case(frames, 6.0)
    return [frame_points(f, 2) for f in views], lo, hi


def run(views, lo, hi, repeats: int, busy: str | None, interval_s: float) -> float:
    """Median ms of a frame's integrate + cloud merge, ``busy``: None, "python", "compiled"."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(interval_s)
    times = []
    try:
        with busy_thread(busy):
            for _ in range(repeats):
                m = OccupancyMap(lo, hi, OccupancyConfig(voxel=0.01, max_range=3.0))
                points3 = np.zeros((0, 3), np.float32)
                keys = np.zeros(0, np.int64)
                cloud = (points3, np.zeros((0, 3), np.uint8), points3, keys, keys)
                for i, (points, eye) in enumerate(views):
                    pts, rgb = points.astype(np.float32), np.zeros((len(points), 3), np.uint8)
                    t0 = time.perf_counter()
                    m.integrate(points, eye)
                    cloud = add_frame(*cloud, pts, rgb, eye.astype(np.float32),
                                      MemoryConfig().cloud_voxel, MAX_CLOUD)  # fmt: skip
                    if i:  # the start view into the fresh map untimed
                        times.append((time.perf_counter() - t0) * 1e3)
    finally:
        sys.setswitchinterval(before)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8, help="frames of the pan")
    parser.add_argument("--repeats", type=int, default=3, help="runs of the pan")
    args = parser.parse_args()
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as child:
        views, lo, hi = child.submit(kitchen, args.frames).result()
    ours = ServiceSettings.model_fields["switch_interval_ms"].default / 1e3
    run(views[:2], lo, hi, 1, None, 0.005)  # warm
    python = "beside a busy Python thread, switch interval"
    cases = [
        ("alone", None, 0.005),
        ("beside a busy compiled thread", "compiled", 0.005),
        (f"{python} 5 ms", "python", 0.005),
        (f"{python} {ours * 1e3:g} ms", "python", ours),
    ]
    ms = []
    for label, busy, interval in cases:
        ms.append(run(views, lo, hi, args.repeats, busy, interval))
        print(f"{label}: {ms[-1]:.1f} ms a kitchen frame (integrate + cloud)", flush=True)
    alone, compiled, python5, python_ours = ms
    print(
        f"frame_ms={alone:.1f} frame_busy_compiled_ms={compiled:.1f} "
        f"frame_busy_python_5ms={python5:.1f} frame_busy_python_0_5ms={python_ours:.1f} "
        f"gil_wait_ms_5ms={python5 - compiled:.1f} gil_wait_ms_0_5ms={python_ours - compiled:.1f}"
    )


if __name__ == "__main__":
    main()
