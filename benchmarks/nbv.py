"""One next-best-view planning step on a 1 cm map of tabletop_clutter (the start view
integrated), everything included, and its information-gain ray casting against two peers on
the same map and rays: first on equal work, then ours as shipped.

- ``plan_step_s``: ``Planner.plan`` with the nbv node's defaults (equidistant views, k = 72,
  the volume measure, the scene's roi): sampling, head IK, line of sight, the skip map,
  hierarchical IG (every 30th ray for all views, every ray for the best 3), the floor map, path
  costs (RRT-Connect where the straight line is blocked) and the utility. Median of
  ``--repeats`` after one warm step (``Planner.warm_up`` first, as the node does).
- ``like_for_like_vs_embree`` (Embree's ms ÷ ours, > 1: ours faster): the coarse IG pass of
  that step (every 30th pixel ray of every candidate view, ~2.2 M rays) against Open3D's
  ``RaycastingScene`` (Embree, C++) with the occupied voxels as boxes (the faces between an
  occupied voxel and a not-occupied one: the same first hits as whole cubes, fewer triangles),
  its first-hit ``cast_rays``. Equal: the same rays (origins and directions, float64 ours,
  float32 Embree's), the same map; the same threads, numba's pool for ours and
  ``cast_rays(nthreads=…)`` with as many for Embree (Open3D's TBB would take every core: the
  same here, pinned all the same); each side's acceleration structure built outside the timing
  (our SkipMap of the map, Embree's BVH of the boxes; both build times printed); both warm (a
  full cast first). Differs, by design of each: Embree finds each ray's first hit only; ours
  walks each ray to its first occupied voxel or the 3 m range and integrates the unknown
  volume in the roi on the way (the IG itself). A lower bound of what any C++ IG over these
  rays costs, since an IG must reach the first hit too; Embree's rays are not cut at 3 m.
- ``rays_per_s`` and ``shipped_vs_embree`` (as shipped): the coarse pass as the planner runs
  it, the SkipMap build included in our time (Embree's BVH build still left out of its own):
  our rays/s and our rate over Embree's.
- ``vs_pyoctomap_castray_loop`` (secondary, not equal work): against a Python loop over
  pyoctomap's ``castRay`` (OctoMap, C++; first hit only, no unknown counting, a binding call
  per ray, one thread) on the rays of every 8th of those views, our rate on the whole pass
  (as shipped) over theirs: mostly the cost of a Python call per ray.

Last line: like_for_like_vs_embree=<x> plan_step_s=<everything included> rays_per_s=<ours,
as shipped> shipped_vs_embree=<x> vs_pyoctomap_castray_loop=<x>. Target (issue 18):
plan_step_s ≤ 0.5 s on the 2-core machine.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numba
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.nbv import information_gain as ig  # noqa: E402
from services.nbv.planner import Planner, PlannerConfig  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World, look_target  # noqa: E402

VOXEL = 0.01
OCTOMAP_EVERY = 8  # castRay on the rays of every 8th view (a Python call per ray)


def start_view_map():
    """The start view of tabletop_clutter integrated into a 1 cm map of the roi ± 1 m:
    (states, origin, the cloud and its origin, the look target, the robot's start, roi)."""
    world = World("tabletop_clutter", ARMAR6)
    centre = look_target(world)
    world.look_at(centre)
    renderer = CameraRenderer(world.model, 640, 480)
    T, stamp = capture.snapshot(world, renderer, "head_rgbd")
    frame = capture.frame(world, renderer, "head_rgbd", T, stamp, 0, np.random.default_rng(0))
    renderer.close()
    roi = world.info.roi
    lo = np.floor((roi[0] - 1.0) / 0.02) * 0.02
    hi = np.ceil((roi[1] + 1.0) / 0.02) * 0.02
    lo[2], hi[2] = -0.04, 2.2
    K = frame.intrinsics
    z = frame.depth.astype(np.float64)
    v, u = np.nonzero(z > 0.35)
    cam = np.column_stack([(u - K.cx) / K.fx * z[v, u], (v - K.cy) / K.fy * z[v, u], z[v, u]])
    points, origin = cam @ T[:3, :3].T + T[:3, 3], T[:3, 3].copy()
    occupancy = OccupancyMap(lo, hi, OccupancyConfig(voxel=VOXEL))
    occupancy.integrate(points, origin)
    map_origin, states = occupancy.states()
    return states, map_origin, points, origin, centre, tuple(world.info.robot_start), roi


def voxel_boxes(states: np.ndarray, origin: np.ndarray, voxel: float):
    """The occupied voxels as a triangle mesh: two triangles per face an occupied voxel shares
    with a voxel that is not (or with the grid's edge), outward. (vertices, triangles)."""
    occ = np.pad(states == ig.OCCUPIED, 1)
    corners = np.array([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], float)
    # per face: axis, side and its four corners (indices into ``corners``) counter-clockwise
    # seen from outside
    faces = [
        (0, -1, (0, 1, 3, 2)), (0, 1, (4, 6, 7, 5)),
        (1, -1, (0, 4, 5, 1)), (1, 1, (2, 3, 7, 6)),
        (2, -1, (0, 2, 6, 4)), (2, 1, (1, 5, 7, 3)),
    ]  # fmt: skip
    verts, tris = [], []
    for axis, side, quad in faces:
        neighbour = np.roll(occ, -side, axis=axis)
        k = np.argwhere(occ & ~neighbour) - 1  # voxel indices of the exposed faces
        base = origin + k * voxel
        quad_v = base[:, None, :] + corners[list(quad)][None] * voxel  # (n, 4, 3)
        n0 = sum(len(v) for v in verts)
        idx = n0 + 4 * np.arange(len(k))[:, None]
        verts.append(quad_v.reshape(-1, 3))
        tris.append(np.concatenate([idx + np.array([0, 1, 2]), idx + np.array([0, 2, 3])]))
    return np.concatenate(verts).astype(np.float32), np.concatenate(tris).astype(np.uint32)


def median_time(fn, repeats: int) -> tuple[float, list[float]]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    # rendered in a child process: the timing process holds no renderer (Mesa's threads, the
    # GL context's memory), as the nbv node's holds none
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as child:
        states, map_origin, points, cloud_origin, centre, start, roi = child.submit(
            start_view_map
        ).result()

    # the planning step, everything included, as the node runs it
    config = PlannerConfig(roi=roi)
    planner = Planner(config, ARMAR6.mjcf, "head_rgbd", "armar6")
    planner.warm_up()

    def plan():
        return planner.plan(
            centre[None], None, states, map_origin, VOXEL, start, np.array([start]), 1
        )

    result = plan()  # warm: the first step on a map of this size
    steps, timings = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        r = plan()
        steps.append(time.perf_counter() - t0)
        timings.append(r.timings_ms)
    step_s = float(np.median(steps))
    parts = {k: float(np.median([t[k] for t in timings])) for k in timings[0]}
    n_views = len(result.candidates.t)
    print(
        f"map {states.shape} at {VOXEL * 100:.0f} cm ({int((states == ig.OCCUPIED).sum())} "
        f"occupied), roi {np.round(roi[0], 2)}..{np.round(roi[1], 2)}; "
        f"{n_views} candidate views, best {result.best} (IG {result.gain[result.best]:.0f}, "
        f"cost {result.cost[result.best]:.2f} s)"
    )
    print(
        f"planning step: median {step_s:.3f} s over {args.repeats} "
        f"(all: {', '.join(f'{x:.3f}' for x in steps)}); median parts: "
        + ", ".join(f"{k} {v:.0f}" for k, v in parts.items())
    )

    # the coarse IG pass of that step: every 30th pixel ray of every candidate view
    poses = result.candidates.poses
    rays = ig.pixel_rays(*config.intrinsics, every=config.every)
    omega = ig.solid_angles(rays, config.intrinsics[2], config.intrinsics[3], config.every)
    box = config.roi
    n_rays = len(poses) * len(rays)

    def ours(skip: ig.SkipMap | None = None) -> np.ndarray:
        if skip is None:
            skip = ig.SkipMap.build(states, map_origin, VOXEL, box)
        return ig.information_gain(
            None, map_origin, VOXEL, poses, rays, config.max_range, skip=skip, solid_angle=omega
        )

    threads = numba.get_num_threads()
    ours()
    ours_s, ours_all = median_time(ours, args.repeats)
    t0 = time.perf_counter()
    for _ in range(args.repeats):
        skip = ig.SkipMap.build(states, map_origin, VOXEL, box)
    skip_s = (time.perf_counter() - t0) / args.repeats
    ours(skip)
    cast_s, cast_all = median_time(lambda: ours(skip), args.repeats)
    ours_rps = n_rays / ours_s

    # the peers' libraries only now: their thread pools (Open3D's) are not there while ours run
    import open3d as o3d
    import pyoctomap

    # Open3D (Embree): the occupied voxels' exposed faces, first hits of the same rays, on as
    # many threads as ours
    t0 = time.perf_counter()
    verts, tris = voxel_boxes(states, map_origin, VOXEL)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(verts), o3d.core.Tensor(tris))
    o3d_rays = np.empty((len(poses), len(rays), 6), np.float32)
    o3d_rays[:, :, :3] = poses[:, None, :3, 3]
    o3d_rays[:, :, 3:] = np.einsum("vij,rj->vri", poses[:, :3, :3], rays)
    o3d_rays = o3d.core.Tensor(o3d_rays.reshape(-1, 6))
    scene.cast_rays(o3d_rays[:1000], nthreads=threads)  # the BVH is built on the first cast
    build_s = time.perf_counter() - t0
    hit = scene.cast_rays(o3d_rays, nthreads=threads)["t_hit"].numpy()
    o3d_s, o3d_all = median_time(lambda: scene.cast_rays(o3d_rays, nthreads=threads), args.repeats)

    # OctoMap: the cloud into a 1 cm tree, castRay per ray from Python, every 8th view
    tree = pyoctomap.OcTree(VOXEL)
    tree.insertPointCloud(points, cloud_origin, 3.0, False, True)
    some = poses[::OCTOMAP_EVERY]
    end = np.zeros(3)

    def octomap() -> int:
        hits = 0
        for view in some:
            o = view[:3, 3].copy()
            for d in rays @ view[:3, :3].T:
                hits += tree.castRay(o, d, end, True, config.max_range)
        return hits

    octomap_hits = octomap()
    oct_s, _ = median_time(octomap, max(1, args.repeats // 2))
    octomap_rps = len(some) * len(rays) / oct_s

    print(
        f"IG coarse pass, {len(poses)} views × {len(rays)} rays = {n_rays:,}, {threads} threads "
        f"each:\n  like for like: ours {cast_s * 1e3:.0f} ms (SkipMap built apart in "
        f"{skip_s * 1e3:.0f} ms; all: {', '.join(f'{x * 1e3:.0f}' for x in cast_all)} ms), "
        f"Open3D RaycastingScene (Embree) first hits {o3d_s * 1e3:.0f} ms ({len(tris):,} "
        f"triangles of {int((states == ig.OCCUPIED).sum()):,} occupied voxels, BVH and mesh "
        f"built apart in {build_s:.2f} s; {int(np.isfinite(hit).sum()):,} of {n_rays:,} hit; "
        f"all: {', '.join(f'{x * 1e3:.0f}' for x in o3d_all)} ms): Embree ÷ ours "
        f"×{o3d_s / cast_s:.2f}"
    )
    print(
        f"  as shipped: ours {ours_s * 1e3:.0f} ms with the SkipMap build = {ours_rps:,.0f} "
        f"rays/s (all: {', '.join(f'{x * 1e3:.0f}' for x in ours_all)} ms); Embree ÷ ours "
        f"×{o3d_s / ours_s:.2f}"
    )
    print(
        f"  pyoctomap castRay loop, every {OCTOMAP_EVERY}th view ({len(some) * len(rays):,} "
        f"rays, {octomap_hits:,} hit): {octomap_rps:,.0f} rays/s; ours (as shipped) ÷ it "
        f"{ours_rps / octomap_rps:.1f}"
    )
    print(
        f"like_for_like_vs_embree={o3d_s / cast_s:.2f} plan_step_s={step_s:.3f} "
        f"rays_per_s={ours_rps:.0f} shipped_vs_embree={o3d_s / ours_s:.2f} "
        f"vs_pyoctomap_castray_loop={ours_rps / octomap_rps:.1f}"
    )


if __name__ == "__main__":
    main()
