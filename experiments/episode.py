"""The exploration episode (thesis Algorithm 5 in a loop, 4.5) in lockstep: every service a
local process on a loopback router, the explorer among them (``services/explorer``, its clock
``lockstep``: it steps the sim while the platform and head move, asks it to render each view,
and holds after each view), and this evaluator outside it: it only subscribes and queries.

    explorer: plan (nbv/plan) → step until platform and head are still → render → the frame
    fused and mapped → held   ·   here: score the view against the ground truth → resume

until the planner stops (u(v̂) below quality, or n views). The first view is taken where the
robot starts, looking at the roi's centre (turning in place first where the neck cannot).
Per view: support-graph precision / recall / F1 (Eq. 4.14-4.16), unknown voxels in the roi,
path cost and its sum, InlierIndex and OverlappingIndex (Eq. 3.11, 3.12), the predicted and
the realised information gain, how the primitives map to bodies, planning time, platform
pose, and the camera pose error after registration (the sim's sensor models drift the
odometry; the truth is always scored with the true camera pose)."""

from __future__ import annotations

import json
import logging
import math
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import zenoh

from avs.launcher import Supervisor
from avs.services import BY_NAME
from experiments import evaluation, scene_figures
from schemas import (
    BasePose,
    BoxQuery,
    ExploreControl,
    ExploreStatus,
    GroundTruth,
    GroundTruthQuery,
    Keys,
    NextBestView,
    OccupancySlice,
    OccupancyStats,
    PoseCorrection,
    RgbdFrame,
    SceneModel,
    SimControl,
    SimStatus,
    decode,
    encode,
)
from services.common.poses import pose_difference

EPISODE_SERVICES = ("sim", "perception", "scene_memory", "nbv", "explorer")
#: how long the evaluator waits for the explorer's next view (a plan, a drive, fusion)
VIEW_WAIT_S = 900.0
#: a view that realises less than this share of its predicted gain is a warning sign
REALISED_SHARE = 0.1
log = logging.getLogger("avs.explore")


@dataclass
class EpisodeConfig:
    scene: str = "tabletop_occluded"
    robot: str = "armar6"
    strategy: str = "utility"
    sampling: str = "equidistant"
    fusion: str = "sg"
    views: int = 10
    seed: int = 0
    voxel: float = 0.01
    ig_measure: str = "volume"  # or "rays": Eq. 4.6 as printed (services/nbv/README.md)
    out: Path = Path("runs/explore")
    host: str = "127.0.0.1"  # the address the router listens on
    scale: dict[str, int] = field(default_factory=dict)  # instances per scalable service
    launch: dict[str, list[str]] = field(default_factory=dict)  # command prefix per service
    ready_timeout: float = 120.0
    #: the robot's sensor models in the sim (noise, bias, latency, odometry drift)
    noise: bool = True
    registration: bool = True  # the scene memory registers each frame before fusing it
    #: every service's output in ``out/logs/<service>.log`` (False: this process's console)
    logs: bool = True
    #: ``avs view`` flags (``--save FILE``, ``--web`` …) to watch the episode with; None: no
    #: viewer
    viewer: tuple[str, ...] | None = None


@dataclass
class ViewRecord:
    view: int
    support_precision: float
    support_recall: float
    support_f1: float
    unknown_voxels: int
    path_cost: float
    accumulated_path_cost: float
    inlier_index: float
    overlapping_index: float
    planning_s: float
    base: list[float]
    information_gain: float = 0.0
    #: goals the platform did not reach in time on the way to this view: abandoned, and
    #: excluded from the plans that followed (``services/explorer``)
    abandoned: int = 0
    goal: list[float] = field(default_factory=list)  # the planned platform pose (Eq. 4.2, 4.3)
    trajectory: list[list[float]] = field(default_factory=list)  # (x, y) driven, every 0.1 s
    planning_workers: int = 1  # nbv instances that evaluated the candidates
    #: the gain the view realised, by the measure that predicted ``information_gain``
    realised_gain: float = 0.0
    vertex_precision: float = 0.0  # primitives that map to a body / all primitives
    segments_per_body: dict[str, int] = field(default_factory=dict)
    bodies_merged: int = 0  # primitives with ≥ 20 % of their points on each of two bodies
    #: the camera pose the map used (odometry, corrected by registration) against the true one
    pose_error_m: float = 0.0
    pose_error_deg: float = 0.0
    registration_ms: float = 0.0
    registration: str = ""  # "accepted", or why the frame kept its prior; "" when off
    #: T_world_camera (4×4, rows) the map used, and the true one the truth is scored with
    camera_pose_used: list[list[float]] = field(default_factory=list)
    camera_pose_true: list[list[float]] = field(default_factory=list)
    rgb: str = ""  # the view's colour image, a JPEG thumbnail in the episode's directory


@dataclass
class EpisodeResult:
    scene: str
    strategy: str
    sampling: str
    fusion: str
    seed: int
    views: list[ViewRecord] = field(default_factory=list)
    terminated_by: str = ""
    termination_detail: str = ""  # why, in words (no_candidates)
    abandoned_goals: int = 0  # goals the platform did not reach in time, all episode long
    final_support_edges: list[list[str]] = field(default_factory=list)
    #: the fused model's primitives: id, kind, the body each maps to, OBB centre and extent,
    #: rotation, colour, the solid (``scene_figures.solid``), stable / unstable / unresolved
    final_primitives: list[dict] = field(default_factory=list)
    #: the fused support edges by primitive: supporter, supported, occ(e), their bodies and the
    #: verdict against the truth ("true", "false_positive", "not_judged": outside the roi)
    final_support: list[dict] = field(default_factory=list)
    final_missed: list[list[str]] = field(default_factory=list)  # true edges not perceived
    robot: str = ""
    noise: bool = True
    registration: bool = True
    camera_hfov_deg: float = 0.0  # the head camera's horizontal field of view (the map's wedges)
    recording: str = ""  # the rerun recording of the episode (``--save-view``), if any
    out: str = ""  # the episode's directory (the views' images are relative to it)
    roi: list[list[float]] = field(default_factory=list)
    centre: list[float] = field(default_factory=list)
    #: the final map's obstacles seen from above (occupied voxels 5 cm-2 m): a PNG in the
    #: episode's directory, with the world position of its corner and its cell size
    floor_png: str = ""
    floor_origin: list[float] = field(default_factory=list)
    floor_cell: float = 0.0

    def to_json(self) -> dict:
        return asdict(self)


def _free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]


@dataclass
class SceneFacts:
    """What the orchestrator needs of a scene: its roi (or a box around its objects), the
    view spheres' centres, where the robot starts, and the map's bounds (avs/bounds.py)."""

    roi_min: np.ndarray
    roi_max: np.ndarray
    centre: np.ndarray  # the roi's centre: the first view looks at it
    start: tuple[float, float, float]
    pois: np.ndarray  # (m, 3) points of interest
    workspace: tuple[np.ndarray, np.ndarray] | None
    map_min: np.ndarray
    map_max: np.ndarray

    @property
    def centres(self) -> np.ndarray:
        """The view spheres' centres: the points of interest if the scene has them (4.5.3)."""
        return self.pois if len(self.pois) else self.centre[None, :]


def scene_facts(scene: str, robot: str, radius: float = 1.5) -> SceneFacts:
    from avs.bounds import map_bounds
    from services.sim.robots import ROBOTS
    from services.sim.world import World, look_target

    world = World(scene, ROBOTS[robot])
    centre = look_target(world)
    if world.info.roi is not None:
        lo, hi = (np.asarray(v, float) for v in world.info.roi)
    else:
        lo, hi = centre - 1.0, centre + 1.0
    pois = np.array([world.info.pois[k] for k in sorted(world.info.pois)]).reshape(-1, 3)
    start = tuple(world.info.robot_start)
    centres = pois if len(pois) else centre[None, :]
    map_lo, map_hi = map_bounds(
        (lo, hi), start[:2], centres, radius=radius, footprint=world.robot.footprint_radius,
        workspace=world.info.workspace,
    )  # fmt: skip
    return SceneFacts(lo, hi, centre, start, pois, world.info.workspace, map_lo, map_hi)


class Latest:
    """The newest decoded message of one key."""

    def __init__(self, session: zenoh.Session, key: str, schema) -> None:
        self.value = None
        self.count = 0
        self.cond = threading.Condition()
        self.schema = schema
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        message = decode(sample.payload.to_bytes(), self.schema)
        with self.cond:
            self.value = message
            self.count += 1
            self.cond.notify_all()

    def wait(self, predicate, timeout: float, what: str):
        deadline = time.monotonic() + timeout
        with self.cond:
            while self.value is None or not predicate(self.value):
                left = deadline - time.monotonic()
                if left <= 0:
                    raise TimeoutError(f"timed out waiting for {what}")
                self.cond.wait(left)
            return self.value


class Trail:
    """The platform's (x, y) every 0.1 s of its clock, as it drives (the report's map)."""

    def __init__(self, session: zenoh.Session, key: str) -> None:
        self.points: list[list[float]] = []
        self.last = -float("inf")
        self.lock = threading.Lock()
        self.sub = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        b = decode(sample.payload.to_bytes(), BasePose)
        with self.lock:
            if b.stamp - self.last >= 0.1 - 1e-9:
                self.points.append([round(b.x, 3), round(b.y, 3)])
                self.last = b.stamp

    def take(self) -> list[list[float]]:
        """The points since the last call."""
        with self.lock:
            points, self.points = self.points, []
        return points


class ViewerProcess:
    """``avs view`` watching the episode from a process of its own, like any outside tool:
    started (and waited for: subscribed) before the first view, stopped (it logs what waits
    and the final map, then writes its recording) before the services."""

    def __init__(
        self, session: zenoh.Session, endpoint: str, robot: str, flags: tuple[str, ...],
        timeout: float,
    ) -> None:  # fmt: skip
        instance = f"episode-{_free_port()}"
        command = [sys.executable, "-m", "avs.cli", "--log-level", "WARNING", "view",
                   "--connect", endpoint, "--robot", robot, "--instance", instance,
                   "--grpc-port", "0", *flags]  # fmt: skip
        self.process: subprocess.Popen | None = subprocess.Popen(command)
        alive = Keys(robot).alive("view", instance)
        deadline = time.monotonic() + timeout
        while not any(r.ok for r in session.liveliness().get(alive, timeout=1.0)):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"the viewer did not start: {' '.join(command)}")
            time.sleep(0.1)

    def stop(self, timeout: float = 120.0) -> None:
        p, self.process = self.process, None
        if p is None:
            return
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
        try:
            p.wait(timeout)
        except subprocess.TimeoutExpired:
            log.warning("the viewer did not stop within %.0f s: killed", timeout)
            p.kill()
            p.wait()


class Episode:
    def __init__(self, config: EpisodeConfig, progress=None) -> None:
        self.c = config
        self.progress = progress
        self.keys = Keys(config.robot)

    def _env(self, data_dir: Path, facts: SceneFacts) -> dict[str, str]:
        c = self.c
        csv = lambda v: ",".join(f"{x:.4f}" for x in np.ravel(v))  # noqa: E731
        extra = {}
        if facts.workspace is not None:
            extra = {"AVS_NBV_WORKSPACE_MIN": csv(facts.workspace[0][:2]),
                     "AVS_NBV_WORKSPACE_MAX": csv(facts.workspace[1][:2])}  # fmt: skip
        return extra | {
            "AVS_SIM_SCENE": c.scene,
            "AVS_SIM_LOCKSTEP": "true",
            "AVS_SIM_SEED": str(c.seed),
            "AVS_SIM_SENSORS": str(c.noise).lower(),
            "AVS_SIM_NOISE": str(c.noise).lower(),
            "AVS_SCENE_MEMORY_REGISTRATION": str(c.registration).lower(),
            # every frame of a lockstep episode is a view the planner chose for its gain: none
            # is skipped as too close to the last (a view 3 mm from the last, skipped, realised
            # nothing, and the planner chose it again until the episode ran out of views)
            "AVS_SCENE_MEMORY_KEYFRAME_MOVE": "0",
            "AVS_SCENE_MEMORY_KEYFRAME_TURN": "0",
            "AVS_SCENE_MEMORY_DATA_DIR": str(data_dir),
            "AVS_SCENE_MEMORY_FUSION": c.fusion,
            "AVS_SCENE_MEMORY_VOXEL": str(c.voxel),
            "AVS_SCENE_MEMORY_BOUNDS_MIN": csv(facts.map_min),
            "AVS_SCENE_MEMORY_BOUNDS_MAX": csv(facts.map_max),
            "AVS_SCENE_MEMORY_ROI_MIN": csv(facts.roi_min),
            "AVS_SCENE_MEMORY_ROI_MAX": csv(facts.roi_max),
            "AVS_NBV_CENTRE": csv(facts.centres),
            "AVS_NBV_FIRST_TARGET": csv(facts.centre),
            "AVS_NBV_ROI_MIN": csv(facts.roi_min),
            "AVS_NBV_ROI_MAX": csv(facts.roi_max),
            "AVS_NBV_STRATEGY": c.strategy,
            "AVS_NBV_SAMPLING": c.sampling,
            "AVS_NBV_MAX_VIEWS": "1000",  # the explorer counts the views (and abandoned goals)
            "AVS_NBV_SEED": str(c.seed),
            "AVS_NBV_IG_MEASURE": c.ig_measure,
            "AVS_PERCEPTION_CAMERA": "registered" if c.fusion != "sg" else "head_rgbd",
            "AVS_EXPLORER_CLOCK": "lockstep",
            "AVS_EXPLORER_HOLD": "true",
            "AVS_EXPLORER_VIEWS": str(c.views),
            "AVS_EXPLORER_ROI_MIN": csv(facts.roi_min),
            "AVS_EXPLORER_ROI_MAX": csv(facts.roi_max),
            "AVS_EXPLORER_CENTRES": csv(facts.centres),
            "AVS_EXPLORER_CAMERA": "head_rgbd",
        }

    def _query(self, session, key: str, request, schema, timeout: float = 60.0):
        """The first reply on ``key``; asked again while nobody answers (a scene memory
        taking over from one that died), up to ``timeout``."""
        return self._queries(session, key, request, schema, timeout)[0]

    def _queries(self, session, key: str, request, schema, timeout: float = 60.0) -> list:
        """Every reply on ``key`` (the pages of a paged one); asked again while nobody
        answers, up to ``timeout``."""
        payload = encode(request) if request is not None else None
        deadline = time.monotonic() + timeout
        while True:
            left = max(0.1, deadline - time.monotonic())
            replies = []
            # every reply, not the last per key (the pages of a paged one)
            replies_of = session.get(
                key, payload=payload, timeout=left, consolidation=zenoh.ConsolidationMode.NONE
            )
            for reply in replies_of:
                if reply.ok is None:
                    raise RuntimeError(f"{key}: {reply.err.payload.to_bytes()[:300]!r}")
                replies.append(decode(reply.ok.payload.to_bytes(), schema))
            if replies:
                return replies
            if time.monotonic() >= deadline:
                raise TimeoutError(f"no reply on {key}")
            time.sleep(0.1)

    def _sim(self, session, **kw) -> SimStatus:
        status = self._query(session, self.keys.sim_control(), SimControl(**kw), SimStatus)
        if not status.ok:
            raise RuntimeError(f"sim/control {kw}: {status.error}")
        return status

    def run(self) -> EpisodeResult:
        c = self.c
        facts = scene_facts(c.scene, c.robot)
        roi_lo, roi_hi = facts.roi_min, facts.roi_max
        c.out.mkdir(parents=True, exist_ok=True)
        data_dir = c.out / "scene_memory"
        shutil.rmtree(data_dir, ignore_errors=True)
        endpoint = f"tcp/{c.host}:{_free_port(c.host)}"
        services = [BY_NAME[n] for n in EPISODE_SERVICES]
        supervisor = Supervisor(
            services, endpoint, c.robot,
            env=self._env(data_dir, facts),
            restart=False, launch=c.launch, scale=c.scale,
            log_dir=c.out / "logs" if c.logs else None,
        )  # fmt: skip
        result = EpisodeResult(
            c.scene, c.strategy, c.sampling, c.fusion, c.seed,
            roi=[list(map(float, roi_lo)), list(map(float, roi_hi))],
            centre=list(map(float, facts.centre)),
            robot=c.robot, noise=c.noise, registration=c.registration, out=str(c.out),
        )  # fmt: skip
        self.supervisor = supervisor
        supervisor.start()
        viewer = None
        try:
            if not supervisor.wait_ready(c.ready_timeout):
                raise RuntimeError(f"services not alive: {supervisor.report()}")
            conf = zenoh.Config()
            conf.insert_json5("mode", '"client"')
            conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
            conf.insert_json5("scouting/multicast/enabled", "false")
            with zenoh.open(conf) as session:
                if c.viewer is not None:
                    viewer = ViewerProcess(session, endpoint, c.robot, c.viewer, c.ready_timeout)
                self._loop(session, result, roi_lo, roi_hi)
                if viewer is not None:  # while the services still answer its map query
                    viewer.stop()
        finally:
            if viewer is not None:
                viewer.stop()
            supervisor.stop()
        return result

    def _loop(self, session, result: EpisodeResult, roi_lo, roi_hi) -> None:
        """Start the explorer's episode and score each view it holds after, then resume it."""
        c, k = self.c, self.keys
        status = Latest(session, k.explore_status(), ExploreStatus)
        base = Latest(session, k.base_state(), BasePose)
        frames = Latest(session, k.rgbd("head_rgbd"), RgbdFrame)
        scenes = Latest(session, k.scene(), SceneModel)
        corrections = Latest(session, k.pose_correction(), PoseCorrection)
        plans = Latest(session, k.next_view(), NextBestView)
        trail = Trail(session, k.base_state())
        self._sim(session, op="reset", scene=c.scene, seed=c.seed)
        self._sim(session, op="step", n=10)
        started = self._control(session, "start")
        episode = started.episode
        roi = BoxQuery(box_min=roi_lo, box_max=roi_hi)
        seen: list[dict[str, np.ndarray]] = []
        accumulated, scored, abandoned = 0.0, 0, 0
        while True:
            s = status.wait(
                lambda m, n=scored: m.episode == episode
                and (m.phase == "done" or (m.phase == "paused" and m.view > n)),
                VIEW_WAIT_S, f"the explorer's view {scored + 1}",
            )  # fmt: skip
            if s.view > scored:
                frame = frames.wait(lambda f, q=s.frame_seq: f.seq >= q, 30,
                                    f"the frame of view {s.view}")  # fmt: skip
                scene = scenes.wait(
                    lambda m, q=frame.seq: m.frame_seq is not None and m.frame_seq >= q, 120,
                    f"the model of view {s.view}",
                )  # fmt: skip
                gt = self._query(
                    session, k.ground_truth(), GroundTruthQuery(camera="head_rgbd"), GroundTruth
                )
                b = base.value
                pose = [b.x, b.y, b.yaw]
                # the map placed the frame at its odometry pose, corrected by registration; the
                # truth is scored where the true camera pose puts it
                T_used, registration_ms, registration = frame.T_world_camera, 0.0, ""
                if c.registration:
                    corr = corrections.wait(lambda m, q=frame.seq: m.frame_seq >= q, 30,
                                            f"frame {frame.seq}'s pose correction")  # fmt: skip
                    T_used = corr.T_world_odom @ frame.T_world_camera
                    registration_ms = corr.registration_ms
                    registration = "accepted" if corr.accepted else corr.reason
                T_true = (
                    gt.T_world_camera if gt.T_world_camera is not None else frame.T_world_camera
                )
                pose_error = pose_difference(T_true, T_used)
                seen.append(evaluation.labelled_points(gt, frame.depth, frame.intrinsics, T_true))
                scores = evaluation.score_primitives(
                    evaluation.merge_points(seen), scene.primitives,
                    scope=evaluation.bodies_in_roi(gt),
                )  # fmt: skip
                support = evaluation.score_support(
                    gt, [(e.supporter, e.supported) for e in scene.support_edges], scores.bodies
                )
                stats = self._query(session, k.occupancy("stats"), roi, OccupancyStats)
                cost = float(s.cost)
                accumulated += cost
                nbv = plans.value
                record = ViewRecord(
                    s.view - 1, support.precision, support.recall, support.f1,
                    int(stats.unknown), cost, accumulated, scores.inlier_index,
                    scores.overlapping_index, s.planning_s, pose, float(s.predicted_gain),
                    s.abandoned - abandoned,
                    list(s.goal), trail.take(), nbv.workers if nbv is not None else 1,
                    stats.realised_volume if c.ig_measure == "volume" else stats.realised_rays,
                    scores.vertex_precision, scores.segments_per_body, scores.bodies_merged,
                    pose_error[0], pose_error[1], registration_ms, registration,
                    np.round(T_used, 6).tolist(), np.round(T_true, 6).tolist(),
                    scene_figures.thumbnail(frame.rgb, c.out / "views" / f"view_{s.view}.jpg",
                                            c.out),
                )  # fmt: skip
                result.views.append(record)
                K = frame.intrinsics
                result.camera_hfov_deg = round(math.degrees(2 * math.atan2(K.width, 2 * K.fx)), 2)
                self._check_gain(result.views)
                edges = [(e.supporter, e.supported) for e in scene.support_edges]
                result.final_support_edges = [
                    list(e) for e in evaluation.edge_names(edges, scores.bodies)
                ]  # every fused edge
                result.final_primitives = [
                    {"id": p.id, "kind": p.model.kind, "body": scores.bodies.get(p.id, ""),
                     "center": [round(float(x), 3) for x in p.obb.center],
                     "extent": [round(float(x), 3) for x in p.obb.extent],
                     "inliers": p.inlier_count, **scene_figures.solid(p),
                     "state": "unstable" if p.id in scene.unstable_ids else "unresolved"
                     if p.id in scene.unresolved_ids else "stable"}
                    for p in scene.primitives
                ]  # fmt: skip
                result.final_support = scene_figures.support_verdicts(
                    scene.support_edges, scores.bodies, support
                )
                result.final_missed = [list(e) for e in support.missed]
                scored, abandoned = s.view, s.abandoned
                if self.progress:
                    self.progress(s.view, c.views, record)
            if s.phase == "done":
                result.abandoned_goals = s.abandoned
                result.terminated_by = s.reason or "max_views"
                result.termination_detail = s.detail if s.reason != "max_views" else ""
                if s.reason not in ("quality", "max_views") and s.detail:
                    log.warning("the explorer stopped (%s): %s", s.reason, s.detail)
                break
            self._control(session, "resume")
        self._floor(session, result)

    def _control(self, session, op: str) -> ExploreStatus:
        status = self._query(session, self.keys.explore_control(), ExploreControl(op=op),
                             ExploreStatus)  # fmt: skip
        if not status.ok:
            raise RuntimeError(f"explore/control {op}: {status.error}")
        return status

    @staticmethod
    def _check_gain(views: list[ViewRecord]) -> None:
        """Warn when two views in a row realised under a tenth of the gain they were chosen
        for: the planner is reasoning on a map the world does not match."""
        low = [v.realised_gain < REALISED_SHARE * v.information_gain for v in views[-2:]]
        if len(low) == 2 and all(low) and views[-1].information_gain > 0:
            a, b = views[-2:]
            log.warning(
                "views %d and %d realised %.0f and %.0f of a predicted %.0f and %.0f "
                "(under %d %%): the map the planner uses may not match the scene",
                a.view, b.view, a.realised_gain, b.realised_gain, a.information_gain,
                b.information_gain, round(100 * REALISED_SHARE),
            )  # fmt: skip

    def _floor(self, session, result: EpisodeResult) -> None:
        """The obstacles of the final map from above, for the report's map of the views."""
        from PIL import Image

        box = BoxQuery(box_min=np.full(3, -1e3), box_max=np.full(3, 1e3))
        piece = OccupancySlice.join(
            self._queries(session, self.keys.occupancy("slice"), box, OccupancySlice)
        )
        v, origin = piece.voxel_size, piece.origin
        k0, k1 = max(0, int((0.05 - origin[2]) / v)), max(1, int((2.0 - origin[2]) / v))
        occupied = np.any(piece.states[:, :, k0:k1] == 2, axis=2)
        seen = np.any(piece.states[:, :, k0:k1] != 0, axis=2)
        image = np.full(occupied.shape, 255, np.uint8)
        image[seen] = 230
        image[occupied] = 60
        Image.fromarray(image.T[::-1]).save(self.c.out / "floor.png")  # rows: +y up
        result.floor_png = str(self.c.out / "floor.png")
        result.floor_origin = [float(origin[0]), float(origin[1])]
        result.floor_cell = float(v)
