"""View registration (issue 15, thesis A.5): one kitchen frame whose pose is off by 5 cm and 3°
registered against the map of the 20 views of ``avs fuse --scene kitchen --path orbit`` (640×480,
depth noise on), by ours (``services/scene_memory/registration.py``: point-to-plane ICP on the
frame's 2 cm then 1 cm cloud against the map's cloud around it, with its acceptance tests) and by
Open3D's plain point-to-point ICP on the full clouds (the frame's every pixel, the whole 1 cm
registered cloud; one pass, 12 cm correspondences, up to 60 iterations), both from the same
prior, both warm, the median of ``--repeats``.

Last line: registration_ms=<ours> speedup_vs_open3d_full=<x> pose_error_mm=<ours>
(pose_error_open3d_mm beside it). Target (issue 15): ≤ 40 ms per frame.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import open3d as o3d  # noqa: E402

from avs.commands.fuse import feasible, path_bases, spread  # noqa: E402
from avs.commands.perceive import look_target  # noqa: E402
from services.scene_memory.memory import MemoryConfig, SceneMemory  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig  # noqa: E402
from services.scene_memory.registration import (  # noqa: E402
    camera_points,
    pose_difference,
    register,
)
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402


def views(n: int, seed: int):
    """The orbit's frames, as ``avs fuse`` renders them."""
    world = World("kitchen", ARMAR6)
    centre = look_target(world)
    bases = []
    for x, y in path_bases(world, "orbit", n, centre):
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        if feasible(world):
            bases.append((x, y))
    renderer = CameraRenderer(world.model, 640, 480)
    rng = np.random.default_rng(seed)
    frames = []
    for i, (x, y) in enumerate(spread(bases, n)):
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        world.look_at(centre)
        T, stamp = capture.snapshot(world, renderer, "head_rgbd")
        frames.append(capture.frame(world, renderer, "head_rgbd", T, stamp, i, rng))
        print(f"\rrendered {i + 1}/{n}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    renderer.close()
    return frames


def perturbed(T: np.ndarray, seed: int) -> np.ndarray:
    """T moved 5 cm and turned 3° about a random axis through the camera."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(3.0)
    out = T.copy()
    out[:3, :3] = (np.eye(3) + math.sin(a) * K + (1 - math.cos(a)) * K @ K) @ T[:3, :3]
    shift = rng.normal(size=3)
    out[:3, 3] += 0.05 * shift / np.linalg.norm(shift)
    return out


def open3d_full(points_camera: np.ndarray, T_prior: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """Plain point-to-point ICP of the full frame against the full map."""
    reg = o3d.pipelines.registration
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points_camera))
    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud))
    result = reg.registration_icp(
        source, target, 0.12, T_prior, reg.TransformationEstimationPointToPoint(),
        reg.ICPConvergenceCriteria(max_iteration=60),
    )  # fmt: skip
    return np.asarray(result.transformation)


def timed(f, repeats: int):
    f()  # warm
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = f()
        times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times), out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=20)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    if args.views < 2 or args.repeats < 1:
        p.error("--views must be ≥ 2 and --repeats ≥ 1")
    frames = views(args.views, args.seed)
    memory = SceneMemory(MemoryConfig(occupancy=OccupancyConfig(voxel=0.02)))
    last = frames[-1]
    for f in frames[:-1]:
        memory.integrate(f)
    cloud = memory.cloud.astype(np.float64)
    T_true = np.asarray(last.T_world_camera)
    T_prior = perturbed(T_true, args.seed)
    ours_pts = camera_points(last.depth, last.intrinsics, 0.35, 3.0)
    full_pts = camera_points(last.depth, last.intrinsics, 0.35, 3.0, stride=1)
    ms_ours, ours = timed(lambda: register(ours_pts, T_prior, cloud), args.repeats)
    ms_o3d, T_o3d = timed(lambda: open3d_full(full_pts, T_prior, cloud), args.repeats)
    err_ours = pose_difference(T_true, ours.T_world_camera)
    err_o3d = pose_difference(T_true, T_o3d)
    print(f"map: {len(cloud)} points of {args.views - 1} views; frame: {len(ours_pts)} points "
          f"(ours, every 2nd pixel), {len(full_pts)} (Open3D, all)")  # fmt: skip
    print(
        f"ours:   {ms_ours:.1f} ms, accepted={ours.accepted} {ours.reason}, fitness "
        f"{ours.fitness:.2f}, error {err_ours[0] * 1e3:.1f} mm {err_ours[1]:.2f} deg"
    )
    print(f"open3d: {ms_o3d:.1f} ms, error {err_o3d[0] * 1e3:.1f} mm {err_o3d[1]:.2f} deg")
    print(
        f"registration_ms={ms_ours:.1f} speedup_vs_open3d_full={ms_o3d / ms_ours:.2f} "
        f"pose_error_mm={err_ours[0] * 1e3:.2f} pose_error_open3d_mm={err_o3d[0] * 1e3:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
