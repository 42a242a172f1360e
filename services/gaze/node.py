"""The gaze node: the real-time service of the system (thesis 5.3, Fig. 5.6).

Every IMU sample (``sensors/imu``, up to 1 kHz) runs one control step of the stabiliser with
the latest ``state/joints`` and ``state/base`` and publishes ``cmd/head`` (joint velocities,
``trigger_stamp`` = the IMU sample's stamp, for latency tracing). The fixation point is the
freshest ``gaze/target`` of the highest priority (next-best-view or a person: manual targets
win while fresh), else the ego-sphere's winner, chosen every ``select_every`` seconds from
object-localisation uncertainty (``perception/observation``, Kalman-fused) and whatever
``gaze/target`` sources put on it. An input older than ``stale_ms`` stops the control: the
head is held still (one zero command) and the node says so, instead of extrapolating."""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque

import numpy as np

from schemas import (
    BasePose,
    EgoSphereSnapshot,
    GazeTarget,
    HeadCommand,
    ImuSample,
    JointState,
    PoseCorrection,
    RgbdFrame,
    SceneObservation,
)
from services.common.node import Node
from services.common.poses import corrected_base
from services.common.robots import JOINT_SPEED, robot_mjcf
from services.gaze.config import GazeSettings
from services.gaze.ego_sphere import EgoSphere
from services.gaze.kinematics import HEAD_JOINTS, GazeKinematics
from services.gaze.okr import RetinalSlip
from services.gaze.saliency import ObjectBelief, colour_blobs, pixel_rays
from services.gaze.sensing import nearest
from services.gaze.stabiliser import GazeStabiliser, StabiliserConfig

log = logging.getLogger("avs.gaze")


def platform_rotation(yaw: float) -> np.ndarray:
    """R_world_platform: the ego-sphere's directions are in the platform frame."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def localisation_covariance(depth: float) -> np.ndarray:
    """A primitive centre's covariance (world axes, roughly): 1 cm of fitting error each way
    (a primitive from one view), plus the structured-light depth noise at its depth
    (σ_z = 0.0012 + 0.0019·(z − 0.4)² m, SPEC §2) along the vertical. One result leaves an
    object above a 1 cm task acuity (salient), two bring it below."""
    sz = 0.0012 + 0.0019 * (depth - 0.4) ** 2 + 0.01
    return np.diag([0.01**2, 0.01**2, sz**2])


#: an ego-sphere winner must be more salient than this (ten times its noise) to call a saccade
SALIENCY_FLOOR = 1e-2

#: the control step's gauges are updated every this many steps
GAUGE_EVERY = 50

#: the OKR measures slip only while fixating: the gaze angle error between two frames stayed
#: below this (rad)
OKR_MAX_ERROR = math.radians(1.0)


def build_stabiliser(settings: GazeSettings) -> GazeStabiliser:
    """The stabiliser as ``settings`` configure it (the node's, and ``avs warm-up``'s)."""
    cameras = settings.fixating()
    return GazeStabiliser(
        GazeKinematics(robot_mjcf(settings.robot), cameras),
        StabiliserConfig(
            HEAD_JOINTS[settings.robot], cameras, gain=settings.gain, damping=settings.damping,
            eye_weight=settings.eye_weight, vor_gain=settings.vor_gain,
            okr_gain=settings.okr_gain, odometry=settings.odometry,
            speed=JOINT_SPEED.get(settings.robot, {}),
        ),
    )  # fmt: skip


class GazeNode:
    def __init__(self, node: Node, settings: GazeSettings) -> None:
        self.node, self.s = node, settings
        cameras = settings.fixating()
        self.joints = HEAD_JOINTS[settings.robot]
        self.stab = build_stabiliser(settings)
        self.kin = self.stab.kin
        self.stab.warm_up()  # before any input: the first control step must be on time
        self.okr_camera = settings.okr_camera or cameras[0]
        if self.okr_camera not in cameras:
            raise ValueError(f"okr_camera {self.okr_camera!r} is not a fixating camera {cameras}")
        self.okr_kin = GazeKinematics(robot_mjcf(settings.robot), [self.okr_camera])
        self.slip: RetinalSlip | None = None
        self.slip_stamp: float | None = None
        self.ego = EgoSphere(settings.points, settings.expiry)
        look = [n for n in self.joints if n not in ("neck_roll", "eye_pan_right")]
        self.ego.prune(self.kin.reachable_directions(cameras[0], look, 5000), 4.0)
        # two locks: ``lock`` for attention (targets, objects, the ego-sphere), ``stab_lock``
        # for the stabiliser (taken last when both are needed); the control step holds the
        # second, so no frame's or observation's work can hold up a head command
        self.lock = threading.Lock()
        self.stab_lock = threading.Lock()
        self.out_lock = threading.RLock()  # cmd/head: a step's command and a hold's zero in order
        self.joint_state: JointState | None = None
        self.joint_names: tuple[str, ...] = ()  # the joint state's names, as a tuple
        # (stamp, sample) in arrival order: joint states for OKR (1 s at 200 Hz), gyro for the VOR
        self.joint_history: deque[tuple[float, JointState]] = deque(maxlen=200)
        self.gyro_history: deque[tuple[float, np.ndarray]] = deque(maxlen=100)
        self.base_history: deque[tuple[float, BasePose]] = deque(maxlen=200)  # 1 s at 200 Hz
        self.base: BasePose | None = None
        #: memory/pose_correction: the registered world from the odometry's (None: not yet)
        self.T_world_odom: np.ndarray | None = None
        self.imu_wall = -math.inf  # wall time of the last IMU sample, for the watchdog
        self.targets: dict[str, GazeTarget] = {}  # the freshest per source
        self.targets_wall: dict[str, float] = {}
        self.current: np.ndarray | None = None  # the fixation point of the last control step
        self.error = math.inf  # the largest gaze angle error (rad) since the last OKR frame
        self.objects: list[ObjectBelief] = []
        self.chosen: np.ndarray | None = None  # ego-sphere winner (world point)
        self.previous: np.ndarray | None = None  # the last winner, held while nothing wins
        self.chosen_at = -math.inf
        self.holding: str = ""  # why the head is held, "" while controlling
        node.metrics.gauge("holding", 0)
        self.commanding = False
        self.seq = 0
        self.steps = 0
        self.imu_seq: int | None = None  # the last IMU sample's seq: gaps are skipped samples
        self.imu_skipped = 0
        node.metrics.gauge("imu_skipped", 0)
        k = node.keys
        self.out_head = node.publisher(k.cmd_head())
        self.out_ego = node.publisher(k.egosphere())
        # the joint states and odometry (200 Hz each) wait for the control loop, which takes
        # them before each step: no thread woken per state (the IMU drives the loop; states
        # without IMU have no step to serve)
        self.joint_states = node.inbox(k.joints(), JointState, size=64)
        self.base_states = node.inbox(k.base_state(), BasePose, size=64)
        node.subscribe(k.pose_correction(), PoseCorrection, self.on_correction)
        node.subscribe(k.gaze_target(), GazeTarget, self.on_target)
        node.subscribe(k.observation(), SceneObservation, self.on_observation)  # each one counts
        # the newest IMU sample only: after a stall the control step acts on the present, not
        # on a backlog of the past (a queue of stale steps delays every command after it)
        node.subscribe(k.imu(), ImuSample, self.on_imu, latest_only=True, name="on_imu")
        if settings.blob_camera:
            node.subscribe(k.rgbd(settings.blob_camera), RgbdFrame, self.on_blobs,
                           latest_only=True, name="on_blobs")  # fmt: skip
        if settings.okr_gain > 0:
            node.subscribe(k.rgbd(self.okr_camera), RgbdFrame, self.on_frame, latest_only=True)
        node.start_thread(self.watchdog, "gaze:watchdog")
        if settings.egosphere_rate > 0:
            node.start_thread(self.publish_egosphere, "gaze:egosphere")

    # -- inputs -------------------------------------------------------------------------------

    def on_joints(self, msg: JointState) -> None:
        if self.joint_state is None or msg.names != self.joint_state.names:
            self.joint_names = tuple(msg.names)  # the control step's key to its indices
        self.joint_state = msg
        self.joint_history.append((msg.stamp, msg))

    def on_base(self, msg: BasePose) -> None:
        self.base = msg
        self.base_history.append((msg.stamp, msg))

    def on_correction(self, msg: PoseCorrection) -> None:
        """View registration's correction of the odometry (thesis A.5): targets are world
        points, so the platform is placed where the registered map has it, not where its
        drifting odometry does."""
        self.T_world_odom = np.asarray(msg.T_world_odom, float)

    def _registered(self, T: np.ndarray) -> np.ndarray:
        """A pose or point the odometry placed (a frame's camera, a primitive from it) in the
        registered world."""
        return T if self.T_world_odom is None else self.T_world_odom @ T

    def _base(self, base: BasePose) -> tuple[tuple[float, float, float], tuple[float, ...]]:
        """The platform's pose and world velocity, corrected by view registration."""
        return corrected_base(self.T_world_odom, (base.x, base.y, base.yaw),
                              (base.v_x, base.v_y, base.v_yaw))  # fmt: skip

    def on_target(self, msg: GazeTarget) -> None:
        with self.lock:
            self.targets[msg.source] = msg
            self.targets_wall[msg.source] = time.monotonic()

    def on_observation(self, obs: SceneObservation) -> None:
        """Fuse each small primitive's centre into the nearest object belief (within 10 cm),
        or start one; each belief's saliency goes on the ego-sphere at its direction."""
        cam = self._registered(np.asarray(obs.T_world_camera, float))
        with self.lock:
            for p in obs.primitives:
                if float(np.max(p.obb.extent)) > 0.4:  # tables, walls, floors: not objects
                    continue
                centre = self._registered(np.append(np.asarray(p.obb.center, float), 1.0))[:3]
                depth = float(np.linalg.norm(centre - cam[:3, 3]))
                R = localisation_covariance(depth)
                near = [b for b in self.objects if np.linalg.norm(b.mean - centre) < 0.1]
                if near:
                    near[0].update(centre, R, obs.stamp)
                else:
                    self.objects.append(ObjectBelief.first(centre, R, obs.stamp, self.s.acuity))

    def on_frame(self, frame: RgbdFrame) -> None:
        """OKR: the retinal slip of the fixation point between this frame and the last, against
        the forward model's camera poses (the joint state and odometry at hand)."""
        base, target = self.base, self.current
        if frame.rgb is None or base is None or target is None:
            return
        with self.stab_lock:
            error, self.error = self.error, 0.0
        if error > OKR_MAX_ERROR:  # a saccade since the last frame: the image swept by and
            self.slip_stamp = None  # tracks break (saccadic suppression: no slip across one)
            return
        # the model's pose of the camera when the frame was taken, not when it arrived (a copy:
        # the joint states' thread appends meanwhile); within 60 % of the states' period (3 ms
        # at 200 Hz): a state further off (late, or lost under load) puts the head where it
        # was not, and the difference would be read as slip
        history = list(self.joint_history)
        period = (history[-1][0] - history[0][0]) / (len(history) - 1) if len(history) > 1 else 0
        js = nearest(history, frame.stamp, 0.6 * period)
        # and the platform where it was then, not where it is now (the frame is 40 ms old)
        base = nearest(list(self.base_history), frame.stamp, 0.6 * period) if period else base
        if js is None or base is None:  # no state of the frame's time: no slip
            self.slip_stamp = None
            return
        kin = self.okr_kin
        joints = dict(zip(js.names, js.position.tolist(), strict=True))
        kin.update(kin.configuration(self._base(base)[0], joints))
        if self.slip is None:
            K = frame.intrinsics
            self.slip = RetinalSlip((K.fx, K.fy, K.cx, K.cy))
        slip = self.slip.update(frame.rgb, kin.camera_pose(self.okr_camera), frame.stamp, target,
                                frame.depth)  # fmt: skip
        last, self.slip_stamp = self.slip_stamp, frame.stamp
        if slip is not None and last is not None and frame.stamp - last < 0.5:
            if float(np.abs(slip).max()) > 1.0:  # > 57°/s of unexplained drift: a bad track
                self.node.drop("implausible_slip", self.okr_camera, f"slip {slip}")
                return
            with self.stab_lock:
                self.stab.observe_slip(self.okr_camera, slip, frame.stamp - last)
            self.node.metrics.gauge("okr_offset_m", float(np.linalg.norm(self.stab.offset)))

    def on_blobs(self, frame: RgbdFrame) -> None:
        """Single-coloured blobs of the frame onto the ego-sphere (5.4.2), a constant saliency
        at each blob's direction (platform frame, from the head), its depth if the frame has
        one."""
        js, base = self.joint_state, self.base
        if frame.rgb is None or js is None or base is None or frame.camera != self.s.blob_camera:
            return
        blobs = colour_blobs(frame.rgb)
        if not blobs:
            return
        K = frame.intrinsics
        uv = np.array([(u, v) for u, v, _ in blobs])
        T_cam = self._registered(np.asarray(frame.T_world_camera, float))
        rays = pixel_rays(uv, (K.fx, K.fy, K.cx, K.cy), T_cam)
        R = platform_rotation(self._base(base)[0][2])
        head = self._head_position()
        directions = []
        for (u, v), ray in zip(uv, rays, strict=True):
            z = float(frame.depth[int(v), int(u)]) if frame.depth is not None else 0.0
            point = T_cam[:3, 3] + ray * (z / ray @ T_cam[:3, 2] if z > 0 else 1.5)
            directions.append(point - head)
        with self.lock:
            for to in directions:
                self.ego.add("blob", R.T @ to, self.s.blob_saliency, frame.stamp,
                             distance=float(np.linalg.norm(to)))  # fmt: skip
        self.node.metrics.gauge("blobs", len(blobs))

    def on_imu(self, imu: ImuSample) -> None:
        """One control step per IMU sample, after the states that came since the last."""
        self.imu_wall = arrived = time.monotonic()
        for js in self.joint_states.take():
            self.on_joints(js)
        for b in self.base_states.take():
            self.on_base(b)
        if self.imu_seq is not None and imu.seq > self.imu_seq + 1:  # stale ones, not taken
            self.imu_skipped += imu.seq - self.imu_seq - 1
            self.node.metrics.gauge("imu_skipped", self.imu_skipped)
        self.imu_seq = imu.seq
        self.gyro_history.append((imu.stamp, np.asarray(imu.angular_velocity, float)))
        js, base = self.joint_state, self.base
        # inputs' ages on the sample clock (sim or wall time alike, lockstep included)
        ages = {"state/joints": js, "state/base": base}
        stale = [k for k, m in ages.items()
                 if m is None or imu.stamp - m.stamp > self.s.stale_ms / 1e3]  # fmt: skip
        if stale:
            self.hold(f"no {' and '.join(stale)} for more than {self.s.stale_ms:.0f} ms")
            return
        target = self.target(imu.stamp, base)
        if target is None:
            self.hold("no fixation target")
            return
        pose, twist = self._base(base)
        with self.stab_lock:
            cmd = self.stab.command_of(
                target,
                pose,
                twist,
                self.joint_names,
                js.position,
                js.velocity,
                # the gyro of the joint state's instant, for the VOR's reafference
                # (ω_gyro − J_ω·v of one instant): the newest gyro against a state up to 5 ms
                # older (200 Hz) counts the head's own acceleration meanwhile as a disturbance,
                # and the VOR, cancelling it, closes a loop of gain up to 2 through the delays,
                # which oscillates; no sample within 2.5 ms: no VOR this step
                nearest(self.gyro_history, js.stamp, 2.5e-3),
                imu.stamp,
                # the joint state is up to 5 ms (200 Hz) plus its latency old: carried forward
                imu.stamp - js.stamp,
            )
            self.current = target + self.stab.offset
            self.error = max(self.error, *cmd.error_rad.values())
        with self.out_lock:  # the watchdog's hold cannot come between
            if time.monotonic() - arrived > self.s.stale_ms / 1e3:
                # a step that took longer than the watchdog waits: it has held the head, and
                # a command this late would undo that
                self.node.metrics.drop("late_step")
                return
            self.out_head.put_fields(  # (encoded unchecked at 1 kHz: the sim validates it)
                HeadCommand, seq=self._seq(), stamp=imu.stamp, names=list(cmd.velocity),
                mode="velocity", values=cmd.array, source="gaze",
                trigger_stamp=imu.stamp,
            )  # fmt: skip
            self.commanding = True
            if self.holding:
                log.info("controlling again", extra={"after": self.holding})
                self.holding = ""
                self.node.metrics.gauge("holding", 0)
        self.steps += 1
        if self.steps % GAUGE_EVERY == 1:  # the metrics at 20 Hz, not at the loop's 1 kHz
            m = self.node.metrics
            m.gauge("fixation_error_deg", math.degrees(max(cmd.error_rad.values())))
            m.gauge("unpredicted_rad_s", math.hypot(*cmd.unpredicted))
            m.gauge("control_steps", self.steps)
            if self.stab.bias is not None:
                m.gauge("gyro_bias_deg_s", math.degrees(math.hypot(*self.stab.bias.bias)))

    def _seq(self) -> int:
        self.seq += 1
        return self.seq

    # -- targets ------------------------------------------------------------------------------

    def target(self, stamp: float, base: BasePose) -> np.ndarray | None:
        """The fresh gaze/target of the highest priority, else the ego-sphere's winner."""
        now = time.monotonic()
        with self.lock:
            fresh = [t for src, t in self.targets.items()
                     if now - self.targets_wall[src] <= t.hold_s]  # fmt: skip
            if fresh:
                best = max(fresh, key=lambda t: (t.priority, t.source == "manual", t.stamp))
                return np.asarray(best.point, float)
            if now - self.chosen_at >= self.s.select_every:
                # nothing salient beyond the noise (all of it fixated and inhibited): the gaze
                # stays where it is rather than wander
                self.chosen = self.select(stamp, base)
                if self.chosen is None:
                    self.chosen = self.previous
                self.previous = self.chosen
                self.chosen_at = now
            return self.chosen

    def select(self, stamp: float, base: BasePose) -> np.ndarray | None:
        """Put the objects' saliencies on the ego-sphere, take the winner, inhibit it."""
        head = self._head_position()
        R = platform_rotation(self._base(base)[0][2])
        self.ego.source("object").values[:] = 0.0  # the beliefs as they are now, drawn anew
        for b in self.objects:
            b.predict(stamp)
            if b.saliency > 0:
                to = b.mean - head
                self.ego.add("object", R.T @ to, b.saliency, stamp,
                             distance=float(np.linalg.norm(to)))  # fmt: skip
        j = self.ego.select(stamp, floor=SALIENCY_FLOOR)
        if j < 0:
            return None
        self.ego.inhibit(j, stamp)
        return head + R @ self.ego.points[j] * self.ego.distance(j, stamp)

    def _head_position(self) -> np.ndarray:
        with self.stab_lock:  # the stabiliser's kinematics, at the last control step
            return self.kin.imu_rotation()[1].copy()

    # -- holding and snapshots ----------------------------------------------------------------

    def hold(self, why: str) -> None:
        """Stop controlling: one zero-velocity command if we were commanding, and say why."""
        with self.out_lock:  # after any command a control step is sending
            if self.commanding:
                self.out_head.put(
                    HeadCommand(
                        seq=self._seq(), stamp=time.time(), names=list(self.joints),
                        mode="velocity", values=np.zeros(len(self.joints)), source="gaze",
                    )
                )  # fmt: skip
                self.commanding = False
            if why != self.holding:
                log.warning("holding the head still: %s", why)
                self.holding = why
                self.node.metrics.gauge("holding", 1)
                self.node.metrics.drop("held:" + why.split(" for ")[0])

    def watchdog(self) -> None:
        """Without IMU samples nothing runs the control step: hold from here."""
        while not self.node.stopping:
            time.sleep(self.s.stale_ms / 2e3)
            silent = time.monotonic() - self.imu_wall
            if silent > self.s.stale_ms / 1e3 and (self.commanding or not self.holding):
                self.hold(f"no sensors/imu for more than {self.s.stale_ms:.0f} ms")

    def publish_egosphere(self) -> None:
        period = 1.0 / self.s.egosphere_rate
        while not self.node.stopping:
            time.sleep(period)
            stamp = self.base.stamp if self.base is not None else 0.0
            with self.lock:
                sal = self.ego.saliency(stamp)
                winner = self.ego.select(stamp, sal)
            keep = np.arange(0, len(self.ego), self.s.egosphere_every)
            self.out_ego.put(
                EgoSphereSnapshot(
                    seq=self._seq(), stamp=stamp, reachable=self.ego.reachable[keep],
                    directions=self.ego.points[keep].astype(np.float32),
                    saliency=sal[keep].astype(np.float32),
                    winner=int(np.searchsorted(keep, winner)) if winner >= 0 else -1,
                    sources=sorted(self.ego.sources), frame="platform",
                )
            )  # fmt: skip
