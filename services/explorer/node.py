"""The explorer node: the exploration loop (``core.py``) on Zenoh, in lockstep or on the wall
clock.

Inputs, all light in their callbacks: odometry (``state/base``, the newest kept), the joint
states (polled, the newest decoded each tick), and, only while a view settles and is captured,
the camera's frames and the scene models (their ``seq`` / ``fused_frames`` read with
``codec.peek``: a 2 MB frame or a 3 MB model is never decoded here, and an idle explorer
receives none). The loop runs on a thread of its own, ``tick_s`` apart on the wall clock;
in lockstep it steps ``sim/control`` by ``step_s`` while the platform and head move, and asks
the sim to render each view. Plans are asked on ``nbv/plan`` (the planner drives the platform
and aims the head: ``execute``); the view's target goes on ``gaze/target`` so that the gaze
stabiliser holds it while the platform drives; occupancy statistics of the roi
(``memory/occupancy/stats``) tell which frame the map took and what a view made known.

``explore/status`` is published on every change; ``explore/control`` starts, pauses, resumes
and stops (a stop or pause sends the platform a zero velocity from the query's own handler, at
once, whatever the loop is doing).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable

import numpy as np

from schemas import (
    BasePose,
    BaseVelocity,
    BoxQuery,
    ExploreControl,
    ExploreStatus,
    GazeTarget,
    GroundTruth,
    GroundTruthQuery,
    JointState,
    NextBestView,
    OccupancyStats,
    PlanRequest,
    RgbdFrame,
    SceneModel,
    SimControl,
    SimStatus,
)
from schemas.codec import peek
from services.common.node import Inbox, Node, RemoteError, Subscription
from services.explorer.config import ExplorerSettings
from services.explorer.core import Exploration, Halt, Limits, Look, Plan, Render, Sensed, View

log = logging.getLogger("avs.explorer")

#: seconds a view's target stays fresh on gaze/target; the loop repeats it every LOOK_EVERY_S
LOOK_HOLD_S, LOOK_EVERY_S = 3.0, 1.0
#: the roi when neither the settings nor the start request give one: everything
EVERYWHERE = (np.full(3, -1e3), np.full(3, 1e3))


class ExplorerNode:
    def __init__(self, node: Node, settings: ExplorerSettings) -> None:
        self.node, self.s = node, settings
        k = node.keys
        self.core = Exploration(
            Limits(
                views=settings.views, head_still=settings.head_still,
                base_still=settings.base_still, settle_hold_s=settings.settle_hold_s,
                settle_timeout_s=settings.settle_timeout_s,
                move_margin_s=settings.move_margin_s,
                capture_timeout_s=settings.capture_timeout_s, hold=settings.hold,
            )
        )  # fmt: skip
        self.lock = threading.RLock()
        self.roi: tuple[np.ndarray, np.ndarray] | None = (
            (np.array(settings.roi_min, float), np.array(settings.roi_max, float))
            if settings.roi_min
            else None
        )
        self.lockstep = settings.clock == "lockstep"
        self.clock = 0.0  # lockstep: sim time stepped plus wall time spent not stepping
        self.base: BasePose | None = None
        self.head_joints: list[str] = []
        self.head_speed: float | None = None
        self.frame_seq: int | None = None
        self.fused_seq: int | None = None
        self.stats: OccupancyStats | None = None
        self.status_seq = 0
        self.planning_s = 0.0
        self._published, self._looked = -1, -math.inf  # the status version said, a look's time
        self.joints_seq = -1  # the newest joint state's seq (lockstep waits for a step's)
        # the robot's states only during an episode (``attend``), the frames (2 MB, 15 a second)
        # and the scene models (MB, 6 a second) only while a view settles and is captured
        # (``watch``): an idle explorer receives nothing (subscribed all along, they took 10 % of
        # a core in the live stack)
        self.joints: Inbox[JointState] | None = None
        self.states: list[Subscription] = []
        self.watching: list[Subscription] = []
        self.stats_at = -math.inf
        self.out_status = node.publisher(k.explore_status())
        self.out_gaze = node.publisher(k.gaze_target())
        self.out_base = node.publisher(k.cmd_base())
        node.serve(k.explore_control(), self.on_control, ExploreControl)
        # autostart: the episode begins once every service it needs has announced itself
        self.waiting_for: list[str] | None = list(settings.needs) if settings.autostart else None
        node.start_thread(self.loop, "explorer:loop")

    # -- inputs (light: Zenoh's callbacks) -----------------------------------------------------

    def on_base(self, base: BasePose) -> None:
        self.base = base

    def on_frame_head(self, payload: bytes) -> bool:
        """A frame's seq, read from its first bytes; the frame is not decoded (False)."""
        seq = peek(payload, "seq").get("seq")
        if isinstance(seq, int):
            self.frame_seq = seq if self.frame_seq is None else max(self.frame_seq, seq)
        return False

    def on_model_head(self, payload: bytes) -> bool:
        """The newest frame a scene model holds (``frame_seq``, ``fused_frames``); not decoded."""
        head = peek(payload, "frame_seq", "fused_frames", limit=None)
        seqs = [s for s in [head.get("frame_seq"), *(head.get("fused_frames") or [])]
                if isinstance(s, int)]  # fmt: skip
        if seqs:
            newest = max(seqs)
            self.fused_seq = newest if self.fused_seq is None else max(self.fused_seq, newest)
        return False

    # -- the loop ------------------------------------------------------------------------------

    def now(self) -> float:
        """The core's clock: monotonic on the wall clock; in lockstep the sim time stepped plus
        the wall time spent waiting without stepping (plans, fusion: ``idle``), so that what
        happens while the robot moves (arrival, settling) is decided on sim time alone."""
        return self.clock if self.lockstep else time.monotonic()

    def idle(self, seconds: float) -> None:
        """Wait without stepping; in lockstep the clock goes on by the wall time waited."""
        t0 = time.monotonic()
        self.node.wait(seconds)
        self.clock += time.monotonic() - t0

    def sense(self) -> Sensed:
        js = self.newest_joints()
        if js is not None:
            self.joints_seq = max(self.joints_seq, js.seq)
            self._joint_speed(js)
        phase = self.core.phase
        if phase == "plan" or (phase == "capture" and time.monotonic() - self.stats_at >= 0.2):
            self.stats, self.stats_at = self._stats(), time.monotonic()
        b, st = self.base, self.stats
        return Sensed(
            now=self.now(),
            base=(b.x, b.y, b.yaw) if b is not None else None,
            base_speed=max(math.hypot(b.v_x, b.v_y), abs(b.v_yaw)) if b is not None else 0.0,
            goal_id=b.goal_id if b is not None else "",
            goal_status=b.goal_status if b is not None else "idle",
            head_speed=self.head_speed,
            frame_seq=self.frame_seq,
            fused_seq=self.fused_seq,
            mapped_seq=st.frame_seq if st is not None else None,
            unknown=st.unknown if st is not None else None,
        )

    def scene_roi(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The roi: given (settings, start request), else the one the sim's scene declares
        (``roi_from_sim``), else none (every voxel counts)."""
        if self.roi is None and self.s.roi_from_sim:
            query = GroundTruthQuery(segmentation=False, support=False)
            try:
                (gt,) = self.node.query(self.node.keys.ground_truth(), query, GroundTruth,
                                        10.0) or [None]  # fmt: skip
            except RemoteError as e:
                log.warning("no roi from the sim: %s", e)
                gt = None
            if gt is not None and gt.roi_min is not None:
                self.roi = (np.asarray(gt.roi_min, float), np.asarray(gt.roi_max, float))
                log.info("the scene's roi, from the sim: %s … %s", self.roi[0], self.roi[1])
        return self.roi

    def centres(self) -> np.ndarray:
        """The view spheres' centres: the settings', else the roi's centre, else none (the
        planner's own settings)."""
        if self.s.centres:
            return np.array(self.s.centres, float).reshape(-1, 3)
        roi = self.roi
        return ((roi[0] + roi[1]) / 2)[None, :] if roi is not None else np.zeros((0, 3))

    def _joint_speed(self, js: JointState) -> None:
        """The head's speed: the fastest of the view's joints (all, before the first view)."""
        names = self.head_joints or list(js.names)
        speeds = [abs(v) for n, v in zip(js.names, js.velocity.tolist(), strict=True)
                  if n in names]  # fmt: skip
        self.head_speed = max(speeds, default=0.0)

    def _stats(self) -> OccupancyStats | None:
        roi = self.roi or EVERYWHERE
        box = BoxQuery(box_min=roi[0], box_max=roi[1])
        try:
            replies = self.node.query(self.node.keys.occupancy("stats"), box, OccupancyStats, 5.0)
        except RemoteError as e:
            log.warning("occupancy statistics: %s", e)
            return self.stats
        return replies[0] if replies else self.stats

    def loop(self) -> None:
        """Turn after turn until the node stops; a turn that fails (a sim not up yet, a query
        refused) is counted and logged, and the loop goes on."""
        while not self.node.stopping:
            try:
                self.turn()
            except Exception as e:
                self.node.drop(f"loop_error:{type(e).__name__}", "explorer:loop", repr(e))
                self.idle(1.0)

    def attend(self, on: bool) -> None:
        """Subscribe to odometry (decoded in the callback: small, 100 a second) and the joint
        states (kept in a ring of 4, the newest decoded when asked), or undeclare them."""
        if on and not self.states:
            k = self.node.keys
            self.joints = self.node.inbox(k.joints(), JointState, 4)
            self.states = [self.joints, self.node.subscribe(k.base_state(), BasePose, self.on_base)]
        elif not on and self.states:
            for sub in self.states:
                sub.undeclare()
            self.states, self.joints = [], None

    def newest_joints(self) -> JointState | None:
        return self.joints.newest() if self.joints is not None else None

    def watch(self, on: bool) -> None:
        """Subscribe to the camera's frames and the scene models, reading only their first
        bytes (``on_frame_head``, ``on_model_head`` refuse every sample: none is decoded), or
        undeclare them."""
        if on and not self.watching:
            k, n = self.node.keys, self.node
            self.watching = [
                n.subscribe(k.rgbd(self.s.camera), RgbdFrame, _never, accept=self.on_frame_head),
                n.subscribe(k.scene(), SceneModel, _never, accept=self.on_model_head),
            ]
        elif not on and self.watching:
            for sub in self.watching:
                sub.undeclare()
            self.watching = []

    def live_services(self) -> set[str]:
        """The services with a live instance now (their ``alive/<service>/<instance>`` tokens)."""
        keys = self.node.keys
        replies = self.node.session.liveliness().get(keys.alive(), timeout=2.0)
        relative = [keys.relative(str(r.ok.key_expr)) or "" for r in replies if r.ok]
        return {r.split("/")[1] for r in relative if r.startswith("alive/")}

    def autostart(self) -> bool:
        """Start the episode once every service in ``needs`` is alive (True: started). Says
        which ones it waits for, once each time that set changes."""
        missing = sorted(set(self.waiting_for or ()) - self.live_services())
        if missing:
            if missing != self.waiting_for:
                log.info("the episode starts once %s %s up", ", ".join(missing),
                         "is" if len(missing) == 1 else "are")  # fmt: skip
                self.waiting_for = missing
            return False
        log.info("%s up: the episode starts", ", ".join(self.s.needs) or "nothing needed")
        self.waiting_for = None
        with self.lock:
            self.core.start(self.now(), self.s.views)
        return True

    def turn(self) -> None:
        """Sense, decide, act, say so; then step (lockstep) or wait a tick."""
        if self.waiting_for is not None and not self.autostart():
            self.idle(0.5)
            return
        phase = self.core.phase
        self.attend(phase in ("plan", "move", "settle", "capture"))
        # while settling (0.3 s at least: the newest frame is known when it ends) and capturing
        self.watch(phase in ("settle", "capture"))
        with self.lock:
            actions = self.core.tick(self.sense())
        self.act(actions)
        with self.lock:
            if self.core.version != self._published:
                self._published = self.core.version
                self.publish_status()
            phase, view = self.core.phase, self.core.current
        holding = view is not None and phase in ("move", "settle", "capture")
        if holding and time.monotonic() - self._looked >= LOOK_EVERY_S:
            self.look(view.target)
            self._looked = time.monotonic()
        # lockstep: the sim moves only when stepped, its first states included (a planner plans
        # from the platform's pose)
        first = phase == "plan" and self.base is None
        if self.lockstep and (phase in ("move", "settle") or first):
            self.step()
        else:
            self.idle(self.s.tick_s if not self.lockstep else 0.01)

    def act(self, actions: list) -> None:
        for a in actions:
            if isinstance(a, Plan):
                self.plan(a)
            elif isinstance(a, Look):
                self.look(a.target)
            elif isinstance(a, Halt):
                self.halt(a.reason)
            elif isinstance(a, Render) and self.lockstep:
                self.sim(op="render")

    def plan(self, a: Plan) -> None:
        roi = self.scene_roi()
        if a.initial:  # the unknown voxels before the first view, counted in the roi now known
            stats = self._stats()
            with self.lock:
                self.core.unknown = stats.unknown if stats is not None else None
        request = PlanRequest(
            step=a.step, initial=a.initial, visited=a.visited, excluded=a.excluded,
            blocked=a.blocked,
            centres=self.centres(), roi_min=roi[0] if roi else None,
            roi_max=roi[1] if roi else None,
        )  # fmt: skip
        if len(a.blocked):
            x, y, dx, dy = a.blocked[-1]
            log.info("planning round where the platform got stuck: at (%.2f, %.2f) driving "
                     "(%.2f, %.2f)", x, y, dx, dy)  # fmt: skip
        t0 = time.monotonic()
        try:
            replies = self.node.query(self.node.keys.plan(), request, NextBestView,
                                      self.s.plan_timeout_s)  # fmt: skip
        except RemoteError as e:
            replies, error = [], str(e)
        else:
            error = "the planner did not answer"
        if not replies:
            with self.lock:
                self.core.plan_failed(error, self.now())
            return
        nbv = replies[0]
        self.planning_s = time.monotonic() - t0
        view = View(
            step=a.step, terminate=nbv.terminate, reason=nbv.reason, detail=nbv.detail,
            base=(nbv.x, nbv.y, nbv.yaw), target=tuple(map(float, nbv.target)),
            information_gain=nbv.information_gain, cost=nbv.cost,
            moves=not a.initial or nbv.cost > 0,
        )  # fmt: skip
        if nbv.joint_names:
            self.head_joints = list(nbv.joint_names)
        if self.lockstep and not nbv.terminate:
            self.await_commands(a.step, ("base", "head") if view.moves else ("head",))
        with self.lock:
            self.act(self.core.planned(view, self.now()))
        log.info("view %d planned: %s", a.step, "terminate " + nbv.reason if nbv.terminate
                 else f"IG {nbv.information_gain:.0f}, cost {nbv.cost:.1f} s, platform to "
                      f"({nbv.x:.2f}, {nbv.y:.2f}, {nbv.yaw:.2f})")  # fmt: skip

    def look(self, target) -> None:
        self.out_gaze.put(
            GazeTarget(seq=self.core.step, stamp=time.time(), point=np.array(target, float),
                       source="nbv", priority=self.s.gaze_priority, hold_s=LOOK_HOLD_S)
        )  # fmt: skip

    def halt(self, reason: str) -> None:
        """The platform to rest now: a zero velocity replaces the goal it drives."""
        self.out_base.put(BaseVelocity(seq=self.core.step, stamp=time.time(), v_x=0.0,
                                       timeout=0.1))  # fmt: skip
        b = self.base
        at = f" at ({b.x:.2f}, {b.y:.2f}, {b.yaw:.2f})" if b is not None else ""
        log.info("platform halted%s: %s", at, reason)

    # -- lockstep ------------------------------------------------------------------------------

    def sim(self, **request) -> SimStatus:
        (status,) = self.node.query(self.node.keys.sim_control(), SimControl(**request),
                                    SimStatus, 60.0) or [None]  # fmt: skip
        if status is None or not status.ok:
            raise RuntimeError(f"sim/control {request}: {status.error if status else 'no reply'}")
        return status

    def step(self) -> None:
        """Lockstep: ``step_s`` of sim time, and the platform and joint states it published
        taken before the next decision (a decision on a state still on its way would make the
        episode depend on the machine's load: the step's reply can overtake the streams)."""
        status = self.sim(op="step", n=max(1, round(self.s.step_s * 1000)))
        deadline = time.monotonic() + 30
        base, joints = status.published.get("base"), status.published.get("joints")
        while not self.node.stopping and time.monotonic() < deadline:
            js = self.newest_joints()
            if js is not None:
                self.joints_seq = max(self.joints_seq, js.seq)
                self._joint_speed(js)
            b = self.base
            if (base is None or (b is not None and b.seq >= base)) and (
                joints is None or self.joints_seq >= joints
            ):
                break
            time.sleep(0.001)
        self.clock += self.s.step_s  # the wall time the step took is not the robot's

    def await_commands(self, step: int, streams: tuple[str, ...]) -> None:
        """Lockstep: the planner's commands of ``step`` applied before the first step."""
        try:
            await_commands(lambda: self.sim(op="status"), step, streams)
        except TimeoutError as e:
            log.warning("%s", e)

    # -- status and control --------------------------------------------------------------------

    def status(self) -> ExploreStatus:
        c, v = self.core, self.core.current
        self.status_seq += 1
        return ExploreStatus(
            seq=self.status_seq, stamp=time.time(), episode=c.episode, phase=c.phase,
            clock=self.s.clock, view=c.view, views=c.views,
            target=np.array(v.target, float) if v is not None else None,
            goal=list(v.base) if v is not None else [],
            predicted_gain=v.information_gain if v is not None else 0.0,
            realised_gain=c.realised_gain, unknown=c.unknown if c.unknown is not None else -1,
            abandoned=c.abandoned, reason=c.reason, detail=c.detail,
            cost=v.cost if v is not None else 0.0, planning_s=self.planning_s,
            frame_seq=c.frame,
        )  # fmt: skip

    def publish_status(self) -> None:
        status = self.status()
        self.out_status.put(status)
        why = ": ".join(w for w in (status.reason, status.detail) if w)
        log.info("explore: %s (view %d/%d)%s", status.phase, status.view, status.views,
                 f", {why}" if why else "")  # fmt: skip

    def on_control(self, request: ExploreControl | None) -> ExploreStatus:
        request = request or ExploreControl()
        now = self.now()
        with self.lock:
            try:
                if request.op == "start":
                    if request.roi_min is not None:
                        self.roi = (request.roi_min, request.roi_max)
                    actions = self.core.start(now, request.views)
                elif request.op == "pause":
                    actions = self.core.pause(now)
                elif request.op == "resume":
                    actions = self.core.resume(now)
                elif request.op == "stop":
                    actions = self.core.stop(now)
                else:
                    actions = []
            except ValueError as e:
                status = self.status()
                status.ok, status.error = False, str(e)
                return status
            for a in actions:  # a halt goes out now, not at the loop's next turn
                if isinstance(a, Halt):
                    self.halt(a.reason)
            return self.status()


def await_commands(
    status: Callable[[], SimStatus], step: int, streams: tuple[str, ...], timeout: float = 30.0
) -> None:
    """Lockstep: wait until the sim applied the planner's commands of ``step`` on ``streams``
    (``SimStatus.applied``). They travel from the planner by a route of their own; the plan's
    reply and the first step can overtake them, and a goal that lands a step late drives
    another trajectory (the episode would depend on the machine's load)."""
    deadline = time.monotonic() + timeout
    while True:
        applied = status().applied
        if all(applied.get(s, -1) >= step for s in streams):
            return
        if time.monotonic() > deadline:
            raise TimeoutError(
                f"the sim has not applied the planner's {'/'.join(streams)} commands of "
                f"step {step} after {timeout:g} s (applied: {applied})"
            )
        time.sleep(0.005)


def _never(_message: object) -> None:
    """The handler of an input whose ``accept`` refuses every sample."""
