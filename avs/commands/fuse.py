"""``avs fuse``: drive the robot through a scripted camera path in one process (sim, perception
and scene memory as libraries, no Zenoh), fuse every view, and write ``DIR/metrics.json`` and
``DIR/fusion.png`` (InlierIndex / OverlappingIndex and the modification counts over the views,
as thesis Fig. 3.10 and 3.11).

Paths: ``orbit`` (an arc around the roi's centre at the start distance, views that would put
the platform into furniture skipped), ``line`` (a sideways line through robot_start, facing
the roi), or a JSON file ``[[x, y], ...]`` of platform positions (each looks at the roi).

With ``--noise on`` (the default) the frames carry the robot's sensor models: structured-light
depth noise, and the camera pose the robot believes: the kinematics of its encoders' readings
with the platform where the drifting odometry puts it (the drift of driving from view to
view); ``--registration on`` (the default) refines each pose against the map first (A.5). The
indices are always scored against ground truth placed with the true camera pose, so a
misregistered view shows in them; each view reports its camera pose error after registration.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from avs.commands._args import ROBOT_HELP, ROBOTS, positive_float, positive_int, scene_help


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fuse",
        help="fuse the views of a scripted camera path; metrics and plot",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scene", default="kitchen", help=scene_help())
    p.add_argument("--robot", default="armar6", choices=ROBOTS, help=ROBOT_HELP)
    p.add_argument("--path", default="orbit", help="orbit | line | FILE (JSON list of [x, y])")
    p.add_argument("--views", type=positive_int, default=20, help="views along the path")
    p.add_argument(
        "--fusion", choices=["pc", "sg", "pc+sg"], default="sg",
        help="how the views' support graphs combine (thesis 3.3)",
    )  # fmt: skip
    p.add_argument("--voxel", type=positive_float, default=0.01, help="occupancy voxel, m")
    p.add_argument("--seed", type=int, default=0, help="seed of the sim's noise")
    p.add_argument(
        "--noise",
        choices=["on", "off"],
        default="on",
        help="the robot's sensor models: depth noise, and odometry drift accumulated along the "
        "path as if driven (off: ground-truth poses and depth)",
    )
    p.add_argument(
        "--registration", choices=["on", "off"], default="on",
        help="register each view against the map before fusing it (thesis A.5)",
    )  # fmt: skip
    p.add_argument(
        "--registration-dof", choices=["planar", "full"], default="planar",
        help="registration solves for the platform's x, y and yaw (planar: odometry's drift) "
        "or all six",
    )  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.set_defaults(func=_fuse)


@dataclass
class ViewMetrics:
    view: int
    inlier_index: float
    overlapping_index: float
    added: int
    modified: int
    removed: int
    unknown_voxels: int
    integrate_ms: float
    fuse_ms: float
    base: list[float]
    #: the camera pose the map used (odometry, registered when on) against the true one
    pose_error_m: float = 0.0
    pose_error_deg: float = 0.0
    registration_ms: float = 0.0
    #: "accepted", or why the frame kept its prior; "" for the first frame and when off
    registration: str = ""
    support_f1: float = 0.0  # the fused support graph against the truth (Eq. 4.14)


def verdict(registration: dict | None) -> str:
    """A registration's outcome as a view records it: "accepted" or the refusal's reason."""
    if registration is None:
        return ""
    return "accepted" if registration["accepted"] else registration["reason"]


def path_bases(world, path: str, views: int, centre: np.ndarray) -> list[tuple[float, float]]:
    """Candidate platform positions of a path (before the feasibility check)."""
    sx, sy, _ = world.info.robot_start
    if path == "orbit":
        r = math.hypot(sx - centre[0], sy - centre[1])
        a0 = math.atan2(sy - centre[1], sx - centre[0])
        span = math.radians(240)
        angles = a0 + np.linspace(-span / 2, span / 2, views * 2)
        return [(centre[0] + r * math.cos(a), centre[1] + r * math.sin(a)) for a in angles]
    if path == "line":
        heading = math.atan2(centre[1] - sy, centre[0] - sx)
        side = np.array([-math.sin(heading), math.cos(heading)])
        return [tuple(np.array([sx, sy]) + t * side) for t in np.linspace(-1.5, 1.5, views * 2)]
    points = json.loads(Path(path).read_text())
    return [(float(p[0]), float(p[1])) for p in points]


def feasible(world) -> bool:
    """The platform does not overlap the scene (checked with MuJoCo's contacts)."""
    m, d = world.model, world.data
    for c in d.contact[: d.ncon]:
        names = [m.body(m.geom_bodyid[g]).name for g in c.geom]
        if c.dist < -0.001 and sum(n.startswith("robot/") for n in names) == 1:
            return False
    return True


def spread(items: list, n: int) -> list:
    if len(items) <= n:
        return items
    return [items[i] for i in np.linspace(0, len(items) - 1, n).round().astype(int)]


def driven(odometry, start: tuple[float, float, float], goal: tuple[float, float, float]) -> None:
    """Feed the odometry the straight drive from ``start`` to ``goal`` in 5 cm steps, turning on
    the way: where a scripted path places the robot, its drift accumulates as if driven."""
    steps = max(1, int(math.hypot(goal[0] - start[0], goal[1] - start[1]) / 0.05))
    turn = math.remainder(goal[2] - start[2], math.tau)
    for k in range(1, steps + 1):
        f = k / steps
        odometry.update((start[0] + f * (goal[0] - start[0]),
                         start[1] + f * (goal[1] - start[1]), start[2] + f * turn))  # fmt: skip


def run_fusion(args: argparse.Namespace, progress=None):
    """The fusion run itself; returns (per-view metrics, the memory, the ground truth)."""
    from avs.bounds import map_bounds
    from experiments import evaluation
    from services.common.poses import pose_difference
    from services.perception.pipeline import Perception, cloud_observation, observation
    from services.scene_memory.fusion import FusionConfig
    from services.scene_memory.memory import MemoryConfig, SceneMemory, registered_cloud
    from services.scene_memory.occupancy import OccupancyConfig
    from services.scene_memory.registration import RegistrationConfig
    from services.sim import capture, ground_truth
    from services.sim.render import CameraRenderer
    from services.sim.robots import ROBOTS
    from services.sim.sensors import EncoderModel, Odometry
    from services.sim.world import World, look_target

    world = World(args.scene, ROBOTS[args.robot])
    centre = look_target(world)
    camera = world.robot.default_cameras[0]
    bases = []
    for x, y in path_bases(world, args.path, args.views, centre):
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        if feasible(world):
            bases.append((x, y))
    bases = spread(bases, args.views)
    roi = world.info.roi
    lo, hi = map_bounds(
        roi if roi is not None else (centre - 1.0, centre + 1.0),
        world.info.robot_start[:2], np.zeros((0, 3)),
        footprint=world.robot.footprint_radius, platform_xy=np.array(bases).reshape(-1, 2),
    )  # fmt: skip
    memory = SceneMemory(
        MemoryConfig(
            bounds_min=tuple(lo),
            bounds_max=tuple(hi),
            fusion=FusionConfig(mode=args.fusion),
            occupancy=OccupancyConfig(voxel=args.voxel),
            registration=RegistrationConfig(dof=args.registration_dof)
            if args.registration == "on"
            else None,
        )
    )
    odometry = encoders = None
    if args.noise == "on" and bases:
        x0, y0 = bases[0]
        pose0 = (x0, y0, math.atan2(centre[1] - y0, centre[0] - x0))
        odometry = Odometry(world.robot.sensors, np.random.default_rng([args.seed, 15]), pose0)
        encoders = EncoderModel(world.robot.sensors, np.random.default_rng([args.seed, 15, 1]))
    renderer = CameraRenderer(world.model, 640, 480)
    perception = Perception()
    rng = np.random.default_rng(args.seed) if args.noise == "on" else None
    edges, closure = ground_truth.support_graph(world.model, world.data, world.info)
    segments_seen = []
    metrics: list[ViewMetrics] = []
    gt = None
    for i, (x, y) in enumerate(bases):
        base = (x, y, math.atan2(centre[1] - y, centre[0] - x))
        world.place(base=base)
        world.look_at(centre)
        T_true, stamp = capture.snapshot(world, renderer, camera)
        T, joints = T_true, world.joint_state()[:2]
        if odometry is not None:  # the pose the robot believes, as the sim's models give it:
            # its kinematics of the encoders' readings, the platform where odometry says
            driven(odometry, odometry.true, base)
            names, q, qd = world.joint_state()
            joints = names, encoders.measure(q, qd)[0]
            T = world.T_world_camera_at(camera, odometry.believed, joints)
        frame = capture.frame(world, renderer, camera, T, stamp, i, rng, joints)
        labels, seg = capture.segmentation(world, renderer, camera)
        gt = capture.ground_truth_message(world, edges, closure, camera, labels, seg)
        memory.integrate(frame)
        integrate_ms = memory.timings_ms["integrate_ms"]
        used = T if memory.T_world_odom is None else memory.T_world_odom @ T
        pose_error = pose_difference(T_true, used)
        if args.fusion == "sg":
            result = perception.perceive(
                frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera
            )
            obs = observation(result, frame, i, "fuse", 3.0, perception.config.stride)
        else:  # the registered cloud of the roi, every view so far: re-extracted whole
            cloud = registered_cloud(memory, frame, box=roi)
            result = perception.perceive_points(
                cloud.points, cloud.viewpoints, cloud.colours, cloud.T_world_camera[:3, 3]
            )
            obs = cloud_observation(result, cloud, i, "fuse")
        update = memory.fuse(obs)
        segments_seen.append(  # the truth, where the true camera pose puts it
            evaluation.labelled_points(gt, frame.depth, frame.intrinsics, T_true)
        )
        scene = memory.scene(i)
        scores = evaluation.score_primitives(
            evaluation.merge_points(segments_seen),
            scene.primitives,
            scope=evaluation.bodies_in_roi(gt),
        )
        support = evaluation.score_support(
            gt, [(e.supporter, e.supported) for e in scene.support_edges], scores.bodies
        )
        unknown = (
            memory.occupancy.counts(*roi)[0] if roi is not None else memory.occupancy.counts()[0]
        )
        metrics.append(
            ViewMetrics(
                i,
                scores.inlier_index,
                scores.overlapping_index,
                update.added,
                update.modified,
                update.removed,
                int(unknown),
                integrate_ms,
                memory.timings_ms["fuse_ms"],
                [x, y],
                pose_error[0],
                pose_error[1],
                memory.timings_ms.get("registration_ms", 0.0),
                verdict(memory.last_registration if i > 0 else None),
                support.f1,
            )
        )
        if progress:
            progress(i + 1, len(bases), metrics[-1])
    renderer.close()
    return metrics, memory, gt


def plot(metrics: list[ViewMetrics], path: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    views = [m.view + 1 for m in metrics]
    fig, (a, b) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    a.plot(views, [m.inlier_index for m in metrics], "o-", label="InlierIndex (Eq. 3.11)")
    a.plot(views, [m.overlapping_index for m in metrics], "s-", label="OverlappingIndex (Eq. 3.12)")
    a.set_ylim(0, 1.02)
    a.set_ylabel("index")
    a.legend(loc="lower right")
    a.set_title(title)
    b.plot(views, [m.added for m in metrics], "o-", label="added")
    b.plot(views, [m.modified for m in metrics], "s-", label="modified")
    b.plot(views, [m.removed for m in metrics], "^-", label="removed")
    b.set_xlabel("view")
    b.xaxis.set_major_locator(MaxNLocator(integer=True))
    b.set_ylabel("primitives")
    b.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _fuse(args: argparse.Namespace) -> int:
    from avs.console import log_to, progress
    from services.sim.scene import SceneError

    log_to(args.out / "logs", "fuse")
    with progress() as display:
        task = display.add_task(f"{args.scene} {args.path}", total=args.views, info="")

        def advance(i: int, n: int, m: ViewMetrics) -> None:
            display.update(task, completed=i, total=n, info=(
                f"InlierIndex {m.inlier_index:.2f}  Overlapping {m.overlapping_index:.2f}  "
                f"support F1 {m.support_f1:.2f}  unknown {m.unknown_voxels}"))  # fmt: skip

        try:
            metrics, _, _ = run_fusion(args, advance)
        except SceneError as e:
            print(f"avs fuse: {e}", file=sys.stderr)
            return 2
    out = {
        "scene": args.scene,
        "path": args.path,
        "fusion": args.fusion,
        "noise": args.noise,
        "registration": args.registration,
        "registration_dof": args.registration_dof,
        "views": [asdict(m) for m in metrics],
    }
    (args.out / "metrics.json").write_text(json.dumps(out, indent=2))
    plot(metrics, args.out / "fusion.png", f"{args.scene}: {args.fusion} fusion, {args.path}")
    print(f"wrote {args.out / 'metrics.json'} and {args.out / 'fusion.png'}")
    return 0
