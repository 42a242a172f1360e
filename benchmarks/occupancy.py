"""One 640×480 depth frame of tabletop_clutter (start view, noise on) integrated into a 1 cm
and a 2 cm map by ours and by pyoctomap's ``insertPointCloud`` (OctoMap, C++), both
discretizing the end points (OctoMap's ``discretize``), max range 3 m. Then the free /
occupied / unknown voxels of the scene's roi are counted in both maps and compared.

Last line: integrate_ms_1cm=<ours> speedup_vs_octomap_1cm=<x> integrate_ms_2cm=<ours>
Targets (issue 5): ≤ 100 ms per frame at 1 cm, ≥ 20× faster than pyoctomap at 1 cm, the same
counts within 1 %.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pyoctomap  # noqa: E402

from avs.commands.perceive import look_target  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402

MAX_RANGE = 3.0


def frame_points(frame) -> tuple[np.ndarray, np.ndarray]:
    K, T = frame.intrinsics, frame.T_world_camera
    z = frame.depth.astype(np.float64)
    v, u = np.nonzero(z > 0.35)
    d = z[v, u]
    cam = np.column_stack([(u - K.cx) / K.fx * d, (v - K.cy) / K.fy * d, d])
    return cam @ T[:3, :3].T + T[:3, 3], T[:3, 3].copy()


def octomap_states(tree, lo: np.ndarray, shape, res: float) -> np.ndarray:
    """An OctoMap tree as a dense grid of ``shape`` voxels of ``res`` from ``lo`` (0 unknown,
    1 free, 2 occupied), its leaves expanded to the finest voxels."""
    shape = np.asarray(shape, int)
    state = np.zeros(shape, np.uint8)
    for leaf in tree.begin_leafs():
        c = np.asarray(leaf.getCoordinate(), float)
        half = leaf.getSize() / 2
        i0 = np.clip(np.round((c - half - lo) / res).astype(int), 0, shape)
        i1 = np.clip(np.round((c + half - lo) / res).astype(int), 0, shape)
        if np.any(i1 <= i0):
            continue
        occupied = tree.isNodeOccupied(leaf.current_node)
        state[i0[0] : i1[0], i0[1] : i1[1], i0[2] : i1[2]] = 2 if occupied else 1
    return state


def octomap_counts(tree, lo: np.ndarray, hi: np.ndarray, res: float) -> tuple[int, int, int]:
    """Unknown / free / occupied voxels of ``res`` in [lo, hi) of an OctoMap tree."""
    state = octomap_states(tree, lo, np.ceil((hi - lo) / res - 1e-9).astype(int), res)
    return int((state == 0).sum()), int((state == 1).sum()), int((state == 2).sum())


def ours(points, origin, lo, hi, voxel, repeats) -> tuple[float, tuple[int, int, int]]:
    times = []
    for _ in range(repeats):
        m = OccupancyMap(lo, hi, OccupancyConfig(voxel=voxel, max_range=MAX_RANGE))
        t0 = time.perf_counter()
        m.integrate(points, origin)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), m.counts(lo, hi)


def octomap(points, origin, lo, hi, voxel, repeats) -> tuple[float, tuple[int, int, int]]:
    times = []
    for _ in range(repeats):
        tree = pyoctomap.OcTree(voxel)
        t0 = time.perf_counter()
        tree.insertPointCloud(points, origin, MAX_RANGE, False, True)
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), octomap_counts(tree, lo, hi, voxel)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    world = World("tabletop_clutter", ARMAR6)
    world.look_at(look_target(world))
    renderer = CameraRenderer(world.model, 640, 480)
    T, stamp = capture.snapshot(world, renderer, "head_rgbd")
    frame = capture.frame(world, renderer, "head_rgbd", T, stamp, 0, np.random.default_rng(0))
    renderer.close()
    points, origin = frame_points(frame)
    # the map: the workspace around the table (the roi grown by 1 m, floor to 2 m); counts on it
    lo = np.floor((world.info.roi[0] - 1.0) / 0.02) * 0.02
    hi = np.ceil((world.info.roi[1] + 1.0) / 0.02) * 0.02
    lo[2], hi[2] = -0.04, 2.0
    OccupancyMap(lo, hi, OccupancyConfig(voxel=0.02)).integrate(points[:100], origin)  # compile
    print(f"{len(points)} points, sensor at {np.round(origin, 2)}, map {np.round(hi - lo, 2)} m")
    results = {}
    for voxel in (0.01, 0.02):
        ms, counts = ours(points, origin, lo, hi, voxel, args.repeats)
        oms, ocounts = octomap(points, origin, lo, hi, voxel, max(1, args.repeats // 3))
        diff = max(abs(a - b) / max(b, 1) for a, b in zip(counts, ocounts, strict=True))
        results[voxel] = (ms, oms)
        print(
            f"{voxel * 100:.0f} cm: ours {ms:8.1f} ms  pyoctomap {oms:8.1f} ms  ×{oms / ms:.1f}   "
            f"unknown/free/occupied ours {counts} octomap {ocounts}  largest difference "
            f"{100 * diff:.2f} %"
        )
    (ms1, oms1), (ms2, _) = results[0.01], results[0.02]
    print(
        f"integrate_ms_1cm={ms1:.1f} speedup_vs_octomap_1cm={oms1 / ms1:.1f} "
        f"integrate_ms_2cm={ms2:.1f}"
    )


if __name__ == "__main__":
    main()
