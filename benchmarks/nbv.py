"""One next-best-view planning step on a 1 cm map of tabletop_clutter (the start view
integrated), with 200 candidate views: hierarchical information gain (every 30th ray for all,
every ray for the best 3), RRT-Connect path costs and the utility; and the IG ray casting
alone against a loop of pyoctomap's ``castRay`` (OctoMap, C++) on the same map and rays.

Last line: plan_step_s=<ours> rays_per_s=<ours> speedup_vs_octomap=<x>
Targets (issue 6): ≤ 2 s per planning step on the 2-core machine, ≥ 30× pyoctomap's ray
throughput.
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
from services.nbv import information_gain as ig  # noqa: E402
from services.nbv.path_cost import FloorMap, PathPlanner  # noqa: E402
from services.nbv.planner import Planner, PlannerConfig  # noqa: E402
from services.nbv.utility import utility  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402

N_CANDIDATES = 200


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
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
    occupancy = OccupancyMap(lo, hi, OccupancyConfig(voxel=0.01))
    occupancy.integrate(points, origin)
    map_origin, states = occupancy.states()
    start = tuple(world.info.robot_start)

    config = PlannerConfig(k=90, roi=roi)
    planner = Planner(config, ARMAR6.mjcf, "head_rgbd", "armar6")
    cands = planner.candidates(centre, None, np.array([start]), (states, map_origin, 0.01))
    poses, bases = cands.poses[:N_CANDIDATES], cands.base[:N_CANDIDATES]
    print(
        f"map {states.shape} at 1 cm, {len(poses)} candidate views (of {len(cands.t)}), "
        f"roi {np.round(roi[0], 2)}..{np.round(roi[1], 2)}"
    )
    rng = np.random.default_rng(0)
    ig.hierarchical(states, map_origin, 0.01, poses[:2], config.intrinsics, best_k=1)  # compile

    def plan_step() -> float:
        t0 = time.perf_counter()
        gain, _ = ig.hierarchical(
            states, map_origin, 0.01, poses, config.intrinsics, 3.0, 30, 3, roi
        )
        floor = FloorMap.from_states(states, map_origin, 0.01, keep_free=[(*start[:2], 0.55)])
        paths = PathPlanner(floor, 0.45, config.vel_lin, config.vel_rot)
        cost = np.array([paths.cost(np.array(start), b)[0] for b in bases])
        u = utility("utility", gain, cost, np.zeros(len(gain)), config.lam, rng)
        assert np.isfinite(u).any()
        return time.perf_counter() - t0

    steps = [plan_step() for _ in range(args.repeats)]
    step_s = float(np.median(steps))

    # the rays of one view (every 30th of 640×480: 10,240), cast by both on the same map
    rays = ig.pixel_rays(*config.intrinsics, every=30)
    view = poses[0]
    dirs = rays @ view[:3, :3].T
    # the skip map is made once per map (as OctoMap's tree is), here over the whole map
    t0 = time.perf_counter()
    skip = ig.SkipMap.build(states, map_origin, 0.01)
    skip_s = time.perf_counter() - t0
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        ig.information_gain(None, map_origin, 0.01, view[None], rays, 3.0, skip=skip)
        times.append(time.perf_counter() - t0)
    ours_rps = len(rays) / float(np.median(times))
    tree = pyoctomap.OcTree(0.01)
    tree.insertPointCloud(points, origin, 3.0, False, True)
    o = view[:3, 3].copy()
    end = np.zeros(3)
    times = []
    for _ in range(max(1, args.repeats // 2)):
        t0 = time.perf_counter()
        hits = sum(tree.castRay(o, d, end, True, 3.0) for d in dirs)
        times.append(time.perf_counter() - t0)
    octomap_rps = len(rays) / float(np.median(times))
    print(
        f"planning step: median {step_s:.2f} s over {args.repeats} "
        f"(all: {', '.join(f'{x:.2f}' for x in steps)})"
    )
    print(
        f"IG rays: ours {ours_rps:,.0f} rays/s, pyoctomap castRay {octomap_rps:,.0f} rays/s "
        f"({hits} of {len(rays)} rays hit); our skip map of the whole map took {skip_s:.3f} s"
    )
    print(
        f"plan_step_s={step_s:.2f} rays_per_s={ours_rps:.0f} "
        f"speedup_vs_octomap={ours_rps / octomap_rps:.1f}"
    )


if __name__ == "__main__":
    main()
