"""The scene memory's registered cloud, a kitchen head pan merged into it frame by frame:
ours (``cloud_merge.add_frame``, one compiled call) against the same merge as a dozen numpy
calls (sort the frame's voxel keys, search them in the cloud's, insert, concatenate, delete
the oldest: the scene memory's code before it), on the same frames into fresh clouds of the
same cap (``memory.MAX_CLOUD``), both warm, the clouds compared point by point.

Twice: alone, and beside one busy Python thread, as the scene memory's node runs its frame
step beside its other threads (fusion, the network's callbacks, the snapshot writer). Every
numpy call that lets the GIL go (a sort, a large ufunc) waits up to the interpreter's switch
interval to take it back; a compiled call lets it go once. Both at the switch interval every
AVS service sets (``ServiceSettings``' ``switch_interval_ms`` default, 0.5 ms, read from it;
CPython's own is 5 ms), as the scene memory's process runs.

Frames: the kitchen's start view and a ±``--pan``° head pan of ``--frames`` frames (640×480,
noise on; rendered in a child process), every 2nd pixel each way (the scene memory's cloud);
medians over the frames after the cloud reached its cap.

Last line: cloud_ms=<ours> numpy_ms=<x> cloud_busy_ms=<ours, a busy thread beside it>
numpy_busy_ms=<x> speedup=<numpy ÷ ours, alone> speedup_busy=<beside the busy thread>
switch_interval_ms=<the services' switch interval, at which both ran>
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
from benchmarks.occupancy import frame_points, pan  # noqa: E402
from services.common.config import ServiceSettings  # noqa: E402
from services.scene_memory.cloud_merge import add_frame  # noqa: E402
from services.scene_memory.fusion import voxel_keys  # noqa: E402
from services.scene_memory.memory import MAX_CLOUD, MemoryConfig  # noqa: E402

VOXEL = MemoryConfig().cloud_voxel


def frames(count: int, degrees: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(float32 points, colours, eye) of every 2nd pixel of the kitchen's pan."""
    _, views = pan("kitchen", count, degrees)
    out = []
    for f in views:
        points, eye = frame_points(f, 2)
        v, u = np.nonzero(f.depth > 0.35)
        keep = (v % 2 == 0) & (u % 2 == 0)
        out.append((points.astype(np.float32), f.rgb[v[keep], u[keep]], eye.astype(np.float32)))
    return out


class NumpyCloud:
    """The merge as numpy calls (the scene memory's ``_add_to_cloud`` before ``add_frame``)."""

    def __init__(self) -> None:
        self.cloud = np.zeros((0, 3), np.float32)
        self.colours = np.zeros((0, 3), np.uint8)
        self.viewpoints = np.zeros((0, 3), np.float32)
        self.keys = np.zeros(0, np.int64)
        self.index = np.zeros(0, np.int64)

    def add(self, pts: np.ndarray, rgb: np.ndarray, eye: np.ndarray) -> None:
        keys = voxel_keys(pts, VOXEL)
        unique, first = np.unique(keys, return_index=True)
        at = np.searchsorted(self.index, unique)
        known = np.zeros(len(unique), bool)
        if len(self.index):
            known = self.index[np.minimum(at, len(self.index) - 1)] == unique
        index = np.insert(self.index, at[~known], unique[~known])
        new = np.sort(first[~known])
        self.cloud = np.concatenate([self.cloud, pts[new]])
        self.colours = np.concatenate([self.colours, rgb[new]])
        seen = np.broadcast_to(eye, (len(new), 3))
        self.viewpoints = np.concatenate([self.viewpoints, seen])
        self.keys = np.concatenate([self.keys, keys[new]])
        drop = len(self.cloud) - MAX_CLOUD
        if drop > 0:
            index = np.delete(index, np.searchsorted(index, self.keys[:drop]))
            self.cloud, self.colours = self.cloud[drop:], self.colours[drop:]
            self.viewpoints, self.keys = self.viewpoints[drop:], self.keys[drop:]
        self.index = index


class CompiledCloud(NumpyCloud):
    def add(self, pts: np.ndarray, rgb: np.ndarray, eye: np.ndarray) -> None:
        self.cloud, self.colours, self.viewpoints, self.keys, self.index = add_frame(
            self.cloud, self.colours, self.viewpoints, self.keys, self.index, pts, rgb, eye,
            VOXEL, MAX_CLOUD,
        )  # fmt: skip


def run(kind: type, views: list, busy: bool) -> tuple[list[float], NumpyCloud]:
    """ms a frame of merging the pan into a fresh cloud (after it reached its cap)."""
    cloud, times = kind(), []
    with busy_thread("python" if busy else None):
        for pts, rgb, eye in views:
            t0 = time.perf_counter()
            cloud.add(pts, rgb, eye)
            if len(cloud.cloud) == MAX_CLOUD:
                times.append((time.perf_counter() - t0) * 1e3)
    return times, cloud


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=48, help="frames of the pan")
    parser.add_argument("--pan", type=float, default=40.0, help="the pan's half angle, degrees")
    args = parser.parse_args()
    # the interpreter as every service runs it (services/common/main.py's run_node)
    interval_ms = ServiceSettings.model_fields["switch_interval_ms"].default
    sys.setswitchinterval(interval_ms / 1e3)
    spawn = multiprocessing.get_context("spawn")
    print(f"rendering the kitchen's pan: {args.frames + 1} frames, ±{args.pan:g}°", flush=True)
    with ProcessPoolExecutor(1, mp_context=spawn) as child:
        views = child.submit(frames, args.frames, args.pan).result()
    run(CompiledCloud, views[:3], False)  # warm: compiled, and both have run once
    run(NumpyCloud, views[:3], False)
    result = {}
    for busy in (False, True):
        ours, a = run(CompiledCloud, views, busy)
        theirs, b = run(NumpyCloud, views, busy)
        same = all(
            np.array_equal(x, y)
            for x, y in ((a.cloud, b.cloud), (a.colours, b.colours),
                         (a.viewpoints, b.viewpoints), (a.index, b.index))
        )  # fmt: skip
        if not same or not ours:
            sys.exit("the clouds differ, or the pan never filled the cloud: no comparison")
        result[busy] = float(np.median(ours)), float(np.median(theirs))
        print(
            f"{'beside a busy Python thread' if busy else 'alone'}, switch interval "
            f"{interval_ms:g} ms: {len(ours)} frames at the "
            f"cap ({MAX_CLOUD:,} points), ours {result[busy][0]:.1f} ms, numpy calls "
            f"{result[busy][1]:.1f} ms (×{result[busy][1] / result[busy][0]:.1f}); "
            f"the same clouds",
            flush=True,
        )
    (ours, numpy_ms), (busy_ms, numpy_busy) = result[False], result[True]
    print(
        f"cloud_ms={ours:.1f} numpy_ms={numpy_ms:.1f} cloud_busy_ms={busy_ms:.1f} "
        f"numpy_busy_ms={numpy_busy:.1f} speedup={numpy_ms / ours:.2f} "
        f"speedup_busy={numpy_busy / busy_ms:.2f} switch_interval_ms={interval_ms:g}"
    )


if __name__ == "__main__":
    main()
