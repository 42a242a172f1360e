"""640×480 depth frames (noise on) into our occupancy map and into OctoMap (pyoctomap's
``insertPointCloud``, C++) bounded the same way: the same box (OctoMap's ``useBBXLimit`` with
the BBX set to our map's bounds), the same maximum range (3 m), the same resolution, both
discretizing the end points (OctoMap's ``discretize``), the same input points: those the scene
memory integrates, every ``--stride``-th pixel each way (its ``map_stride``, 2: rays 7 mm apart
at 2 m, finer than the 1 cm voxels to 2.9 m), and for reference every pixel. Three cases:
tabletop_clutter's start view at 1 cm and 2 cm (the map: the roi grown by 1 m, floor to 2 m),
and kitchen's start view at 1 cm (the map the live stack gives the kitchen, avs/bounds.py:
long rays, many past the 3 m range, to the far walls).

The frames are rendered in a child process (MuJoCo, EGL) and only their arrays come back: the
timing process holds no renderer (Mesa's threads, the GL context's memory), as the scene
memory's process holds none.

Each case is a head pan, as the live stack sees it: ``--frames`` distinct frames (8) with the
head turned from −``--pan`` to +``--pan`` degrees (±6°) around the start view, in that order.
Each side integrates the start view once untimed (warm: the map's buffers touched, as the scene
memory's are from frame to frame), then the pan, every frame timed once; medians over the pan,
ours over ``--repeats`` (3) runs of it into fresh maps (OctoMap, seconds a frame, runs once).
Distinct frames, not one frame again and again: repeating a frame would let the free space
saturate (OctoMap skips updates of a voxel at its clamp, we cross whole blocks of them) far
sooner than a moving camera does. Then the unknown / free / occupied voxels of the map's box
are counted in both maps and compared, and in ours with every ray walked whole (what our early
stop of the rays in cleared space changes).

Last line: integrate_ms_1cm=<table-top> integrate_ms_2cm=<table-top>
integrate_ms_kitchen_1cm=<kitchen> speedup_vs_octomap_bbx=<table-top, 1 cm>
Targets (issue 18): kitchen ≤ 60 ms, table-top ≤ 40 ms, ≥ 10× the bounded OctoMap, the same
counts within 1-2 %.
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

import pyoctomap  # noqa: E402

from avs.commands.perceive import look_target  # noqa: E402
from services.scene_memory import occupancy  # noqa: E402
from services.scene_memory.memory import MemoryConfig  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402

MAX_RANGE = 3.0


def frame_points(frame, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """World points of every ``stride``-th pixel each way with a return past 0.35 m, and the
    sensor's position."""
    K, T = frame.intrinsics, frame.T_world_camera
    z = frame.depth.astype(np.float64)
    v, u = np.nonzero(z > 0.35)
    keep = (v % stride == 0) & (u % stride == 0)
    v, u = v[keep], u[keep]
    d = z[v, u]
    cam = np.column_stack([(u - K.cx) / K.fx * d, (v - K.cy) / K.fy * d, d])
    return cam @ T[:3, :3].T + T[:3, 3], T[:3, 3].copy()


def pan(scene: str, frames: int, degrees: float) -> tuple[World, list]:
    """The scene's start view (the robot facing the roi's centre) and ``frames`` views with
    the head turned from −``degrees`` to +``degrees`` around it: the RGB-D frames."""
    world = World(scene, ARMAR6)
    target = look_target(world)
    world.face(target)
    eye = world.T_world_camera("head_rgbd")[:3, 3]
    renderer = CameraRenderer(world.model, 640, 480)
    rng = np.random.default_rng(0)
    views = []
    for seq, angle in enumerate([0.0, *np.linspace(-degrees, degrees, frames)]):
        c, s = np.cos(np.radians(angle)), np.sin(np.radians(angle))
        d = target - eye
        world.look_at(eye + np.array([c * d[0] - s * d[1], s * d[0] + c * d[1], d[2]]))
        T, stamp = capture.snapshot(world, renderer, "head_rgbd")
        views.append(capture.frame(world, renderer, "head_rgbd", T, stamp, seq, rng))
    renderer.close()
    return world, views


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


def every_ray(views, lo, hi, voxel) -> tuple[int, int, int]:
    """Our counts with every ray walked whole (no early stop, ``_walk``): what the early stop
    changes, beside what OctoMap differs by anyway."""
    saved = occupancy.PATIENCE, occupancy.PATIENCE_REST
    occupancy.PATIENCE = occupancy.PATIENCE_REST = 0
    try:
        m = OccupancyMap(lo, hi, OccupancyConfig(voxel=voxel, max_range=MAX_RANGE))
        for points, origin in views:
            m.integrate(points, origin)
        return m.counts(lo, hi)
    finally:
        occupancy.PATIENCE, occupancy.PATIENCE_REST = saved


def ours(views, lo, hi, voxel, repeats: int = 1) -> tuple[float, float, tuple[int, int, int]]:
    """Median ms of ``integrate`` over the pan (``views[1:]``) into one map after the start
    view (``views[0]``, untimed), over ``repeats`` runs of the pan into fresh maps (the same
    maps each time: the machine's noise, not ours, differs), the start view's own ms into the
    first fresh map, and the counts."""
    times, first = [], []
    for _ in range(repeats):
        m = OccupancyMap(lo, hi, OccupancyConfig(voxel=voxel, max_range=MAX_RANGE))
        for i, (points, origin) in enumerate(views):
            t0 = time.perf_counter()
            m.integrate(points, origin)
            (times if i else first).append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), first[0], m.counts(lo, hi)


def bounded_tree(lo, hi, voxel):
    """An OcTree whose updates stay in the voxels of [lo, hi) (BBX: the extreme voxels'
    centres, so that no key on the boundary is in doubt)."""
    tree = pyoctomap.OcTree(voxel)
    tree.setBBXMin(np.asarray(lo, np.float64) + voxel / 2)
    tree.setBBXMax(np.asarray(hi, np.float64) - voxel / 2)
    tree.useBBXLimit(True)
    return tree


def octomap(views, lo, hi, voxel) -> tuple[float, float, tuple[int, int, int]]:
    """Median ms of pyoctomap's ``insertPointCloud`` over the pan into one bounded tree after
    the start view (untimed, as ours), the median ms of the binding's own Python-level
    discretize in it (a set of key tuples, before the C++ call), and the counts."""
    tree = bounded_tree(lo, hi, voxel)
    times, binding = [], []
    for points, origin in views:
        t0 = time.perf_counter()
        tree.insertPointCloud(points, origin, MAX_RANGE, False, True)
        t1 = time.perf_counter()
        tree._discretizePointCloud(points)
        t2 = time.perf_counter()
        times.append((t1 - t0) * 1e3)
        binding.append((t2 - t1) * 1e3)
    return (
        float(np.median(times[1:])),
        float(np.median(binding[1:])),
        octomap_counts(tree, lo, hi, voxel),
    )


def inputs(frames: int, degrees: float) -> list[tuple]:
    """The cases' (name, voxel, frames, lo, hi), each stride taken later: the pans of both
    scenes and their maps' bounds."""

    world, views = pan("tabletop_clutter", frames, degrees)
    # the workspace around the table (the roi grown by 1 m, floor to 2 m)
    lo = np.floor((world.info.roi[0] - 1.0) / 0.02) * 0.02
    hi = np.ceil((world.info.roi[1] + 1.0) / 0.02) * 0.02
    lo[2], hi[2] = -0.04, 2.0
    cases = [("table-top", 0.01, views, lo, hi), ("table-top", 0.02, views, lo, hi)]
    return [*cases, kitchen_case(frames, degrees)]


def kitchen_case(frames: int, degrees: float) -> tuple:
    """("kitchen", 0.01, its pan's frames, lo, hi): the live stack's kitchen map
    (avs/explore.py's scene_facts) on the 2 cm grid."""
    from avs.bounds import map_bounds

    world, views = pan("kitchen", frames, degrees)
    info = world.info
    pois = np.array([info.pois[k] for k in sorted(info.pois)]).reshape(-1, 3)
    lo, hi = map_bounds(
        info.roi, info.robot_start[:2], pois if len(pois) else look_target(world)[None, :],
        footprint=world.robot.footprint_radius, workspace=info.workspace,
    )  # fmt: skip
    lo, hi = np.floor(lo / 0.02) * 0.02, np.ceil(hi / 0.02) * 0.02
    return "kitchen", 0.01, views, lo, hi


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=8, help="frames of the pan (≥ 3)")
    parser.add_argument("--pan", type=float, default=6.0, help="the pan's half angle, degrees")
    parser.add_argument("--repeats", type=int, default=3,
                        help="our runs of each pan (medians over all their frames; OctoMap's "
                        "seconds a frame run once)")  # fmt: skip
    parser.add_argument("--stride", type=int, default=MemoryConfig().map_stride,
                        help="every n-th pixel each way (default: the scene memory's "
                        "map_stride, %(default)s)")  # fmt: skip
    args = parser.parse_args()
    if args.frames < 3 or args.stride < 1 or args.repeats < 1:
        parser.error("--frames must be ≥ 3, --stride and --repeats ≥ 1")
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(1, mp_context=spawn) as child:
        rendered = child.submit(inputs, args.frames, args.pan).result()
    cases = []
    for name, voxel, views, lo, hi in rendered:
        cases.append((name, voxel, args.stride, views, lo, hi))
        if voxel == 0.01:  # and for reference every pixel
            cases.append((name, voxel, 1, views, lo, hi))

    results = {}
    for name, voxel, stride, frames, lo, hi in cases:
        views = [frame_points(f, stride) for f in frames]
        points, origin = views[0]
        far = np.linalg.norm(points - origin, axis=1) > MAX_RANGE
        print(
            f"{name}, {'every pixel' if stride == 1 else f'one pixel in {stride} each way'}: "
            f"{len(views) - 1} frames of a ±{args.pan:g}° pan after the start view "
            f"({len(points)} points, {far.mean():.0%} past {MAX_RANGE:g} m), sensor at "
            f"{np.round(origin, 2)}, map {np.round(lo, 2)}–{np.round(hi, 2)} "
            f"({np.prod(np.ceil((hi - lo) / voxel - 1e-9)) / 1e6:.0f} M voxels at "
            f"{voxel * 100:.0f} cm)",
            flush=True,
        )
        ms, first, counts = ours(views, lo, hi, voxel, args.repeats)
        oms, binding, ocounts = octomap(views, lo, hi, voxel)
        full = every_ray(views, lo, hi, voxel)
        diff, full_diff, stop_diff = (
            max(abs(a - b) / max(b, 1) for a, b in zip(x, y, strict=True))
            for x, y in ((counts, ocounts), (full, ocounts), (counts, full))
        )
        results[name, voxel, stride] = (ms, oms)
        print(
            f"  {voxel * 100:.0f} cm: ours {ms:7.1f} ms a frame ({len(views) - 1} × "
            f"{args.repeats}; the start view into the fresh "
            f"map {first:.1f} ms)   OctoMap (BBX) {oms:8.1f} ms ×{oms / ms:.1f}"
            f" (of it the binding's Python discretize {binding:.1f} ms; without: "
            f"×{(oms - binding) / ms:.1f})\n"
            f"    unknown/free/occupied in the map: ours {counts} OctoMap {ocounts}, largest "
            f"difference {100 * diff:.2f} % (ours casting every ray whole {full}: "
            f"{100 * full_diff:.2f} % from OctoMap's; the early stop changes ours by "
            f"{100 * stop_diff:.2f} %)",
            flush=True,
        )
    (ms1, oms1), (ms2, _), (msk, _) = (
        results["table-top", 0.01, args.stride],
        results["table-top", 0.02, args.stride],
        results["kitchen", 0.01, args.stride],
    )
    (px1, opx1), (pxk, opxk) = results["table-top", 0.01, 1], results["kitchen", 0.01, 1]
    print(
        f"every pixel: table-top 1 cm {px1:.1f} ms (OctoMap ×{opx1 / px1:.1f}), kitchen 1 cm "
        f"{pxk:.1f} ms (OctoMap ×{opxk / pxk:.1f})"
    )
    print(
        f"(the scene memory's input, one pixel in {args.stride} each way:)\n"
        f"integrate_ms_1cm={ms1:.1f} integrate_ms_2cm={ms2:.1f} integrate_ms_kitchen_1cm={msk:.1f} "
        f"speedup_vs_octomap_bbx={oms1 / ms1:.1f}"
    )


if __name__ == "__main__":
    main()
