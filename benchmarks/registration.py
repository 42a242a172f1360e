"""View registration (issue 15, thesis A.5): one kitchen frame whose pose is off by 5 cm and 3° (in
the ground plane and about the vertical, as a wheeled platform's odometry errs) registered
against the map of the other 19 views of ``avs fuse --scene kitchen --path orbit`` (640×480,
depth noise on, the views at their true poses), all from the same prior, the median of
``--repeats``, every one warm; first on equal work, then ours as shipped.

Like for like (``like_for_like_vs_open3d_p2l``: Open3D's ms ÷ ours, > 1: ours faster): ours
(``services/scene_memory/registration.py``) against Open3D's ``registration_icp`` doing our
passes. Equal: the same six unknowns (ours with ``dof="full"``; as shipped it solves for the
three a wheeled platform's odometry gets wrong, x, y and yaw), the same three passes coarse to
fine, each with the same source cloud (the frame averaged on the pass's source voxel and
thinned, by the same function, ``_sources``, inside both timings), the same target (the voxel
means of the 19 views at the pass's map voxel: 8, 3 and 1.5 cm, Open3D's taken from our map),
point-to-plane with Tukey's loss of the same k (4, 2, 1.5 cm), the same correspondence distance
(16, 6, 3 cm) and at most the same 30 iterations a pass, each pass from the last one's pose; one
thread each (ours' kernels are serial; ``o3d.utility.set_max_threads(1)``, CPU time printed to
show it); every structure either side searches built outside the timing: ours the map with every
plane the frame meets fitted (a registration of the frame first, untimed), Open3D's target
normals (estimated on the voxel means, radius two voxels) and its k-d trees
(``registration_icp`` builds a KDTreeFlann of its target inside every call: the median time of
building the three apart is taken off its time; both printed). Differs, by design of each: ours
matches a point to its voxel's mean (or one around its nearest corner) through a hash, Open3D to
its nearest target point through the k-d tree; ours' planes are fitted to the raw points of the
3×3×3 voxels around the match and none where they are thicker than the pass's ``thickness``
(edges, corners), Open3D's normals to the nearest means; ours weighs each point by its depth's
noise (1/σ(z)²), Open3D's point-to-plane takes no weights; a pass ends on a step under 0.1 mm
(ours) or on fitness and RMSE changing by under 1e-6 (Open3D's default criteria); ours also
checks that the map is there before and scores the result after (fitness, RMSE, the conditioning
of the system).

As shipped (``registration_ms``, ``shipped_vs_open3d_*``): ours as the scene memory runs it
(``RegistrationConfig()``: planar), each repeat on a fresh copy of the map, so the planes the
frame needs refitted (those of voxels that have grown since) are fitted inside the timing;
beside it, the same with no plane fitted yet (``cold``) and the map update the frame then costs
(``RegistrationMap.add``), which the Open3D peers do not need but pay for in their k-d tree and
normals. The peers as called, on Open3D's default threads (every core), k-d trees and normals
inside their time:
- Open3D's plain point-to-point ICP on the full clouds (the frame's every pixel, the whole 1 cm
  registered cloud; one pass, 12 cm correspondences, up to 60 iterations): the issue's peer;
- Open3D's point-to-plane ICP as AVS ran it before (the frame at 2 cm then 1 cm against the
  registered cloud around it at 2 cm, normals estimated on it, Tukey's loss, 12 then 4 cm
  correspondences).
Not equal work: named as such.

Last line: like_for_like_vs_open3d_p2l=<x> registration_ms=<ours as shipped>
shipped_vs_open3d_full=<x> pose_error_mm=<ours> ... (the rest beside it). Target (issue 15):
≤ 40 ms per frame.
"""

from __future__ import annotations

import argparse
import copy
import gc
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
from services.scene_memory.memory import MemoryConfig, SceneMemory  # noqa: E402
from services.scene_memory.occupancy import OccupancyConfig  # noqa: E402
from services.scene_memory.registration import (  # noqa: E402
    RegistrationConfig,
    RegistrationMap,
    _sources,
    camera_points,
    pose_difference,
    register,
)
from services.scene_memory.voxel_map import means  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World, look_target  # noqa: E402


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
    """T moved 5 cm in a random direction of the ground plane and turned 3° (random sign)
    about the vertical through the camera: the platform's odometry error (its camera's height
    and tilt are the kinematics'; a 6-DOF error is refused as off the plane)."""
    rng = np.random.default_rng(seed)
    a = math.radians(3.0) * rng.choice((-1.0, 1.0))
    Rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    out = T.copy()
    out[:3, :3] = Rz @ T[:3, :3]
    heading = rng.uniform(0, 2 * math.pi)
    out[:2, 3] += 0.05 * np.array([math.cos(heading), math.sin(heading)])
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


def open3d_p2l(points_camera: np.ndarray, T_prior: np.ndarray, cloud: np.ndarray) -> np.ndarray:
    """Coarse-to-fine point-to-plane ICP with Tukey's loss on Open3D's downsampled clouds."""
    reg = o3d.pipelines.registration

    def down(p: np.ndarray, voxel: float) -> o3d.geometry.PointCloud:
        return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(voxel)

    world = points_camera @ T_prior[:3, :3].T + T_prior[:3, 3]
    source = down(world, 0.02)
    lo, hi = source.get_min_bound() - 0.3, source.get_max_bound() + 0.3
    target = down(cloud[np.all((cloud >= lo) & (cloud <= hi), axis=1)], 0.02)
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(0.05, 30))
    stop = reg.ICPConvergenceCriteria(max_iteration=60)
    coarse = reg.registration_icp(
        source, target, 0.12, np.eye(4),
        reg.TransformationEstimationPointToPlane(reg.TukeyLoss(0.03)), stop,
    )  # fmt: skip
    fine = reg.registration_icp(
        down(world, 0.01), target, 0.04, coarse.transformation,
        reg.TransformationEstimationPointToPlane(reg.TukeyLoss(0.02)), stop,
    )  # fmt: skip
    return np.asarray(fine.transformation) @ T_prior


def open3d_targets(the_map: RegistrationMap) -> list[o3d.geometry.PointCloud]:
    """Each level of our map as Open3D's target: its voxel means, normals estimated on them
    (within two voxels, at most 30 neighbours)."""
    out = []
    for level in the_map.levels:
        n = len(level)
        pcd = o3d.geometry.PointCloud(
            o3d.utility.Vector3dVector(means(level.index[:n], level.stats[:n], level.voxel))
        )
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(2 * level.voxel, 30))
        out.append(pcd)
    return out


def open3d_equal(
    points_camera: np.ndarray,
    T_prior: np.ndarray,
    targets: list[o3d.geometry.PointCloud],
    config: RegistrationConfig,
) -> np.ndarray:
    """Open3D's point-to-plane ICP doing our passes: each pass's source (``_sources``) against
    its level of our map, Tukey's k, correspondence distance and iterations as ours, from the
    last pass's pose."""
    reg = o3d.pipelines.registration
    T = T_prior
    for p, source, target in zip(config.passes, _sources(points_camera, config), targets,
                                 strict=True):  # fmt: skip
        result = reg.registration_icp(
            o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source)), target, p.distance, T,
            reg.TransformationEstimationPointToPlane(reg.TukeyLoss(p.kernel)),
            reg.ICPConvergenceCriteria(max_iteration=config.iterations),
        )  # fmt: skip
        T = result.transformation
    return np.asarray(T)


def timed(f, repeats: int, setup=lambda: None):
    """The median ms of ``f(setup())`` over ``repeats`` (after one warm call), its median CPU
    ms, and its result. Python's garbage collector runs before each call, not inside it (this
    process holds the rendered frames and the memory: a full collection landing in a timing
    added ~12 ms to whichever contestant it hit)."""
    f(setup())  # warm
    times, cpu, out = [], [], None
    for _ in range(repeats):
        arg = setup()
        gc.collect()
        t0, c0 = time.perf_counter(), time.process_time()
        out = f(arg)
        times.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return statistics.median(times), statistics.median(cpu), out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--views", type=int, default=20)
    p.add_argument("--repeats", type=int, default=11)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    if args.views < 2 or args.repeats < 1:
        p.error("--views must be ≥ 2 and --repeats ≥ 1")
    frames = views(args.views, args.seed)
    config = RegistrationConfig()  # as shipped: planar
    full = RegistrationConfig(dof="full")  # like for like: Open3D's six unknowns
    memory = SceneMemory(MemoryConfig(occupancy=OccupancyConfig(voxel=0.02)))
    the_map = RegistrationMap(config)
    last = frames[-1]
    for i, f in enumerate(frames[:-1]):
        memory.integrate(f)  # true poses: the map is the truth the frame is registered to
        T = np.asarray(f.T_world_camera)
        pts = camera_points(f.depth, f.intrinsics, 0.35, 3.0)
        if len(the_map):  # as the memory does: register (fitting planes), then add
            register(pts, T, the_map, config)
        the_map.add(pts @ T[:3, :3].T + T[:3, 3])
        print(f"\rintegrated {i + 1}/{len(frames) - 1}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    cloud = memory.cloud.astype(np.float64)
    T_true = np.asarray(last.T_world_camera)
    T_prior = perturbed(T_true, args.seed)
    ours_pts = camera_points(last.depth, last.intrinsics, 0.35, 3.0)
    full_pts = camera_points(last.depth, last.intrinsics, 0.35, 3.0, stride=1)

    def fresh() -> RegistrationMap:
        return copy.deepcopy(the_map)

    def cold() -> RegistrationMap:
        out = copy.deepcopy(the_map)
        for level in out.levels:
            level.fitted[:] = 0
        return out

    def fitted() -> RegistrationMap:
        """A fresh copy with every plane the frame meets fitted (the frame registered once)."""
        out = copy.deepcopy(the_map)
        register(ours_pts, T_prior, out, full)
        return out

    def ours_fn(m: RegistrationMap):
        return register(ours_pts, T_prior, m, config)

    def ours_full(m: RegistrationMap):
        return register(ours_pts, T_prior, m, full)

    # like for like: one thread each, every searched structure built apart
    targets = open3d_targets(the_map)
    o3d.utility.set_max_threads(1)
    try:
        ms_eq, cpu_eq, ours_eq = timed(ours_full, args.repeats, fitted)
        ms_o3d, cpu_o3d, T_o3d = timed(
            lambda _: open3d_equal(ours_pts, T_prior, targets, full), args.repeats
        )
        ms_trees, _, _ = timed(
            lambda _: [o3d.geometry.KDTreeFlann(t) for t in targets], args.repeats
        )
    finally:
        o3d.utility.set_max_threads(0)
    ms_o3d_eq = ms_o3d - ms_trees

    # as shipped, the peers as called
    ms_ours, _, ours = timed(ours_fn, args.repeats, fresh)
    ms_cold, _, _ = timed(ours_fn, args.repeats, cold)
    world = ours_pts @ T_true[:3, :3].T + T_true[:3, 3]
    ms_add, _, _ = timed(lambda m: m.add(world), args.repeats, fresh)
    ms_full, _, T_full = timed(lambda _: open3d_full(full_pts, T_prior, cloud), args.repeats)
    ms_p2l, _, T_p2l = timed(lambda _: open3d_p2l(ours_pts, T_prior, cloud), args.repeats)
    err_ours = pose_difference(T_true, ours.T_world_camera)
    err_eq = pose_difference(T_true, ours_eq.T_world_camera)
    err_o3d = pose_difference(T_true, T_o3d)
    err_full = pose_difference(T_true, T_full)
    err_p2l = pose_difference(T_true, T_p2l)
    print(f"map: {len(cloud)} points of {args.views - 1} views ({len(the_map)} voxels of "
          f"{the_map.levels[-1].voxel * 100:.1f} cm); frame: {len(ours_pts)} points (every 2nd "
          f"pixel), {len(full_pts)} (all)")  # fmt: skip
    print(
        f"like for like, one thread each, our passes:\n"
        f"  ours (planes fitted apart):      {ms_eq:6.1f} ms (CPU {cpu_eq:.1f}), "
        f"accepted={ours_eq.accepted} {ours_eq.reason}, error {err_eq[0] * 1e3:.1f} mm "
        f"{err_eq[1]:.2f} deg\n"
        f"  open3d p2l tukey, our passes:    {ms_o3d_eq:6.1f} ms ({ms_o3d:.1f} (CPU {cpu_o3d:.1f}) "
        f"less {ms_trees:.1f} for the three k-d trees it builds inside; targets "
        f"{', '.join(str(len(t.points)) for t in targets)} points), error "
        f"{err_o3d[0] * 1e3:.1f} mm {err_o3d[1]:.2f} deg: Open3D ÷ ours ×{ms_o3d_eq / ms_eq:.2f}"
    )
    print(
        f"as shipped (ours), the peers as called:\n"
        f"  ours:              {ms_ours:6.1f} ms ({ms_cold:.1f} cold; + {ms_add:.1f} ms to add "
        f"the frame to the map), accepted={ours.accepted} {ours.reason}, fitness "
        f"{ours.fitness:.2f}, error {err_ours[0] * 1e3:.1f} mm {err_ours[1]:.2f} deg"
    )
    print(f"  open3d p2p full:   {ms_full:6.1f} ms, error {err_full[0] * 1e3:.1f} mm "
          f"{err_full[1]:.2f} deg")  # fmt: skip
    print(f"  open3d p2l tukey:  {ms_p2l:6.1f} ms, error {err_p2l[0] * 1e3:.1f} mm "
          f"{err_p2l[1]:.2f} deg")  # fmt: skip
    print(
        f"like_for_like_vs_open3d_p2l={ms_o3d_eq / ms_eq:.2f} registration_ms={ms_ours:.1f} "
        f"shipped_vs_open3d_full={ms_full / ms_ours:.1f} pose_error_mm={err_ours[0] * 1e3:.2f} "
        f"pose_error_deg={err_ours[1]:.3f} registration_cold_ms={ms_cold:.1f} "
        f"map_add_ms={ms_add:.1f} open3d_full_ms={ms_full:.1f} "
        f"pose_error_open3d_full_mm={err_full[0] * 1e3:.2f} open3d_p2l_ms={ms_p2l:.1f} "
        f"shipped_vs_open3d_p2l={ms_p2l / ms_ours:.1f} "
        f"pose_error_open3d_p2l_mm={err_p2l[0] * 1e3:.2f} like_for_like_ms={ms_eq:.1f} "
        f"open3d_like_for_like_ms={ms_o3d_eq:.1f} "
        f"pose_error_open3d_like_for_like_mm={err_o3d[0] * 1e3:.2f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
