"""The sim's node: commands in, sensor streams out, control and ground truth on queryables.

Threads: the physics loop (realtime mode) steps the world on the wall clock and publishes IMU,
joint and base states at their rates; the render worker owns the OpenGL context and renders the
cameras, periodically in realtime mode and on request (``render``, segmentation) in both modes.
One lock guards the world; rendering holds it only to copy the scene.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import numpy as np

from schemas import (
    ArmCommand,
    BaseGoal,
    BasePose,
    BaseVelocity,
    GroundTruth,
    GroundTruthQuery,
    HeadCommand,
    ImuSample,
    JointState,
    RgbdFrame,
    SimControl,
    SimStatus,
    encode_fields,
)
from services.common.node import Node
from services.common.realtime import ordinary
from services.common.transport import LOSSLESS
from services.sim import capture, ground_truth
from services.sim.config import SimSettings
from services.sim.render import CameraRenderer
from services.sim.robots import ROBOTS
from services.sim.sensors import RobotSensors
from services.sim.world import World

log = logging.getLogger("avs.sim")


class RenderWorker:
    """The one thread that renders. Jobs are callables taking the renderer."""

    def __init__(self, sim: SimNode) -> None:
        self.sim = sim
        self.jobs: queue.Queue[tuple[Callable[[CameraRenderer], Any], Future]] = queue.Queue()
        self.renderer: CameraRenderer | None = None
        self.periodic = not sim.settings.lockstep and sim.settings.fps > 0

    def submit(self, job: Callable[[CameraRenderer], Any], timeout: float = 30.0) -> Any:
        future: Future = Future()
        self.jobs.put((job, future))
        return future.result(timeout)

    def _make_renderer(self) -> CameraRenderer:
        s = self.sim.settings
        return CameraRenderer(self.sim.world.model, s.width, s.height, shadows=s.shadows)

    def run(self) -> None:
        ordinary()  # rendering competes like any other work; physics and IMU come first
        node = self.sim.node
        self.renderer = self._make_renderer()
        period = 1.0 / self.sim.settings.fps if self.periodic else None
        next_frame = time.monotonic()
        while not node.stopping:
            timeout = max(0.0, next_frame - time.monotonic()) if period else 0.2
            try:
                job, future = self.jobs.get(timeout=timeout)
            except queue.Empty:
                if period and not self.sim.paused:
                    self.sim.publish_frames(self.renderer)
                    next_frame = max(next_frame + period, time.monotonic() - period)
                continue
            try:
                if self.renderer.model is not self.sim.world.model:  # after a reset
                    self.renderer.close()
                    self.renderer = self._make_renderer()
                future.set_result(job(self.renderer))
            except Exception as e:
                future.set_exception(e)
        self.renderer.close()


class SimNode:
    def __init__(self, node: Node, settings: SimSettings, world: World) -> None:
        self.node, self.settings, self.world = node, settings, world
        self.robot = world.robot
        self.lock = threading.RLock()
        self.paused = False
        self.slips = 0
        self.rng = np.random.default_rng(settings.seed)
        self.sensors = self._sensors(settings.seed)
        #: the encoders' last reading: (the step it was taken at, joint names, positions)
        self.measured: tuple[int, list[str], np.ndarray] | None = None
        self.cameras = settings.cameras or list(self.robot.default_cameras)
        for c in self.cameras:
            self.robot.camera(c)  # raises on an unknown camera
        k = node.keys
        self.out_frames = {c: node.publisher(k.rgbd(c)) for c in self.cameras}
        # on the wall clock a late 1 kHz sample is worth nothing and is dropped under congestion
        # (the key table's QoS); in lockstep the driver decides on what the streams say, so
        # they wait for a slow subscriber (and the sim with them) rather than lose a sample
        qos = LOSSLESS if settings.lockstep else {}
        self.out_imu = node.publisher(k.imu(), **qos)
        self.out_joints = node.publisher(k.joints(), **qos)
        self.out_base = node.publisher(k.base_state(), **qos)
        self.seq: dict[str, int] = {}  # the newest seq given to a message of each stream
        self.published: dict[str, int] = {}  # ... and the newest put on the wire
        self.applied: dict[str, int] = {}  # the newest command's seq applied, per command stream
        self._gt_cache: tuple[np.ndarray, list, list] | None = None
        node.subscribe(k.cmd_base(), (BaseGoal, BaseVelocity), self.on_cmd_base)
        # on the wall clock, head commands (1 kHz from the gaze) wait for the physics loop,
        # which applies them between two steps: no thread woken per command, no lock handed
        # back and forth; in lockstep each is applied as it comes (the driver steps after)
        self.head_commands = self.arm_commands = None
        if settings.lockstep:
            node.subscribe(k.cmd_head(), HeadCommand, self.on_head_command)
            node.subscribe(k.cmd_arm(), ArmCommand, self.on_arm_command)
        else:
            self.head_commands = node.inbox(k.cmd_head(), HeadCommand, size=64)
            self.arm_commands = node.inbox(k.cmd_arm(), ArmCommand, size=64)
        node.serve(k.sim_control(), self.on_control, SimControl)
        node.serve(k.ground_truth(), self.on_ground_truth, GroundTruthQuery)
        self.worker = RenderWorker(self)
        node.start_thread(self.worker.run, "sim:render")
        if not settings.lockstep:
            node.start_thread(self.physics_loop, "sim:physics")
        log.info(
            "simulating",
            extra={
                "scene": world.info.name,
                "robot": self.robot.name,
                "lockstep": settings.lockstep,
                "cameras": self.cameras,
            },
        )

    def _sensors(self, seed: int) -> RobotSensors | None:
        """The robot's sensor models from the world's current (true) platform pose, or None
        with ``sensors`` off."""
        if not self.settings.sensors:
            return None
        x, y, yaw, *_ = self.world.base_pose()
        return RobotSensors(self.robot.sensors, seed, (x, y, yaw))

    def _next_seq(self, stream: str) -> int:
        self.seq[stream] = self.seq.get(stream, -1) + 1
        return self.seq[stream]

    def _sent(self, stream: str) -> None:
        """The newest message of ``stream`` (the one given the latest seq) went out."""
        self.published[stream] = self.seq[stream]

    # -- physics ------------------------------------------------------------------------------

    def _every(self, rate: float) -> int:
        return max(1, round(1.0 / (rate * self.world.timestep)))

    def advance(self, n: int) -> None:
        """n physics steps, publishing IMU and states when due (call with the lock held)."""
        w = self.world
        imu_every, state_every = (
            self._every(self.settings.imu_rate),
            self._every(self.settings.state_rate),
        )
        for _ in range(n):
            self.apply_head_commands()
            w.step()
            if w.steps % imu_every == 0:
                self.publish_imu()
            if w.steps % state_every == 0:
                self.publish_state()
            if self.sensors is not None:  # joint states whose latency has passed
                for seq, js in self.sensors.joint_states.due(w.time):
                    self.out_joints.put_raw(js)
                    self.published["joints"] = seq

    def physics_loop(self) -> None:
        """Keep sim time on the wall clock (times --speed); slip rather than burst when behind."""
        speed = self.settings.speed
        wall0, sim0, world = time.monotonic(), self.world.time, self.world
        while not self.node.stopping:
            w = self.world
            if self.paused or w is not world:  # paused, or reset to a new world
                wall0, sim0, world = time.monotonic(), w.time, w
                if self.paused:
                    with self.lock:  # the newest command waits for the resume in the world
                        self.apply_head_commands()
                    time.sleep(0.01)
                continue
            target = sim0 + (time.monotonic() - wall0) * speed
            due = int((target - w.time) / w.timestep)
            if due > 100:  # more than 0.1 s behind: do not try to catch up, slip the clock
                self.slips += 1
                self.node.metrics.gauge("physics_slips", self.slips)
                wall0, sim0 = time.monotonic(), w.time
                due = 1
            if due > 0:
                # in slices of at most 5 ms of sim time: commands (a head velocity lasts only
                # 0.1 s) and queries wait at most one slice for the lock, however far behind
                with self.lock:
                    self.advance(min(due, 5))
            else:  # sleep until the next step is due, not a whole step: late wake-ups would
                # make the IMU come in bursts of two
                time.sleep(max(0.0, (w.time + w.timestep - target) / speed))

    # -- publishing ---------------------------------------------------------------------------

    def publish_imu(self) -> None:
        gyro, acc, quat = self.world.imu()
        stamp = self.world.time
        if self.sensors is not None:
            dt = 1.0 / self.settings.imu_rate
            gyro, acc = self.sensors.imu.measure(gyro, acc, dt)
            stamp = self.sensors.imu.stamp(stamp)
        # (the 1 kHz streams are encoded from the simulator's own state without a model or
        # pydantic's checks, half their cost; every receiver validates what it decodes)
        self.out_imu.put_fields(
            ImuSample,
            seq=self._next_seq("imu"),
            stamp=stamp,
            angular_velocity=gyro,
            linear_acceleration=acc,
            orientation=quat,
        )
        self._sent("imu")

    def publish_state(self) -> None:
        w, sensors = self.world, self.sensors
        names, q, qd = w.joint_state()
        if sensors is not None:
            q, qd = sensors.encoders.measure(q, qd)
            self.measured = (w.steps, names, q)
        js = encode_fields(
            JointState,
            seq=self._next_seq("joints"), stamp=w.time, names=names, position=q, velocity=qd,
        )  # fmt: skip
        if sensors is not None:  # published when its latency has passed (advance)
            sensors.joint_states.push(w.time, (self.seq["joints"], js))
        else:
            self.out_joints.put_raw(js)
            self._sent("joints")
        x, y, yaw, vx, vy, vyaw = w.base_pose()
        if sensors is not None:  # what the odometry believes
            x, y, yaw = sensors.odometry.update((x, y, yaw))
            yaw = math.atan2(math.sin(yaw), math.cos(yaw))
            vx, vy, vyaw = sensors.base_velocity(vx, vy, vyaw)
        self.out_base.put_fields(
            BasePose,
            seq=self._next_seq("base"),
            stamp=w.time,
            x=x,
            y=y,
            yaw=yaw,
            v_x=vx,
            v_y=vy,
            v_yaw=vyaw,
            goal_id=w.base.goal_id,
            goal_status=w.base.status,
        )
        self._sent("base")

    def measured_joints(self) -> tuple[list[str], np.ndarray]:
        """The joint positions as the encoders read them now (sensor models on; lock held):
        the joint state measured at this step if there is one (a lockstep frame falls on the
        state rate's grid: the frame's joints are that state's), else a reading of their
        own."""
        w, sensors = self.world, self.sensors
        if self.measured is not None and self.measured[0] == w.steps:
            return self.measured[1], self.measured[2]
        names, q, qd = w.joint_state()
        return names, sensors.encoders.measure(q, qd)[0]

    def frame(self, renderer: CameraRenderer, camera: str) -> RgbdFrame:
        """Render one camera at the current state (render thread only). The frame carries
        the pose the robot believes its camera has: with the sensor models, the forward
        kinematics of the joints as the encoders read them (the frame's ``joint_positions``)
        with the platform where the odometry believes it is; without, the truth."""
        with self.lock:
            T, stamp = capture.snapshot(self.world, renderer, camera)
            joints = self.world.joint_state()[:2]
            if self.sensors is not None:
                joints = self.measured_joints()
                x, y, yaw, *_ = self.world.base_pose()
                base = self.sensors.odometry.update((x, y, yaw))
                T = self.world.T_world_camera_at(camera, base, joints)
        rng = self.rng if self.settings.noise else None
        return capture.frame(
            self.world, renderer, camera, T, stamp, self._next_seq(f"rgbd/{camera}"), rng, joints
        )

    def publish_frames(self, renderer: CameraRenderer) -> int:
        """Render and publish every camera; on the wall clock with the sensor models on, each
        frame goes out its latency after its capture (lockstep frames go out when rendered: the
        driver waits for them)."""
        for camera in self.cameras:
            frame = self.frame(renderer, camera)
            if self.sensors is not None and not self.settings.lockstep:
                late = frame.stamp + self.sensors.spec.frame_latency - self.world.time
                if late > 0:
                    time.sleep(late / self.settings.speed)
            self.out_frames[camera].put(frame)
        return len(self.cameras)

    # -- inputs -------------------------------------------------------------------------------

    def on_cmd_base(self, cmd: BaseGoal | BaseVelocity) -> None:
        with self.lock:
            if isinstance(cmd, BaseGoal):
                self.world.set_base_goal(cmd.x, cmd.y, cmd.yaw, cmd.path, cmd.goal_id)
            else:
                self.world.set_base_velocity(cmd.v_x, cmd.v_y, cmd.v_yaw, cmd.timeout)
            self.applied["base"] = cmd.seq

    def apply_head_commands(self) -> None:
        """The head and arm commands that came since the last step, in order (lock held)."""
        if self.head_commands is not None:
            for cmd in self.head_commands.take():
                self.on_cmd_head(cmd)
        if self.arm_commands is not None:
            for arm in self.arm_commands.take():
                self.on_cmd_arm(arm)

    def on_arm_command(self, cmd: ArmCommand) -> None:
        """An arm command as it comes (lockstep)."""
        with self.lock:
            self.on_cmd_arm(cmd)

    def on_cmd_arm(self, cmd: ArmCommand) -> None:
        """Apply one arm command (lock held); a robot without that arm, or joints not of it,
        are refused and counted."""
        try:
            refused = self.world.command_arm(
                cmd.arm, cmd.mode, cmd.names, cmd.values, cmd.goal, cmd.gripper
            )
        except KeyError as e:
            refused = [str(e)]
        self.applied["arm"] = cmd.seq
        if refused and self.node.metrics.drop("unknown_joint"):
            log.warning("ignoring arm command for %s: %s", cmd.arm, refused)

    def on_head_command(self, cmd: HeadCommand) -> None:
        """A head command as it comes (lockstep)."""
        with self.lock:
            self.on_cmd_head(cmd)

    def on_cmd_head(self, cmd: HeadCommand) -> None:
        """Apply one head command (lock held)."""
        unknown = self.world.command_joints(cmd.names, cmd.mode, cmd.values)
        self.applied["head"] = cmd.seq
        if unknown and self.node.metrics.drop("unknown_joint"):
            log.warning(
                "ignoring commands for unknown joints %s (known: %s)",
                unknown,
                self.world.joint_names,
            )

    # -- queryables ---------------------------------------------------------------------------

    def status(self, ok: bool = True, error: str = "") -> SimStatus:
        return SimStatus(
            ok=ok,
            error=error,
            mode="lockstep" if self.settings.lockstep else "realtime",
            scene=self.world.info.name,
            robot=self.robot.name,
            sim_time=self.world.time,
            steps=self.world.steps,
            paused=self.paused,
            published=dict(self.published),
            applied=dict(self.applied),
        )

    def on_control(self, request: SimControl | None) -> SimStatus:
        if request is None or request.op == "status":
            return self.status()
        op = request.op
        if op == "reset":
            robot = request.robot or self.robot.name
            if robot != self.robot.name:
                return self.status(
                    False, f"this sim runs {self.robot.name}; start another with --robot {robot}"
                )
            scene = request.scene or str(self.world.info.path)
            world = World(
                scene, ROBOTS[robot], timestep=self.settings.timestep, sleep=self.settings.sleep
            )
            with self.lock:
                self.world = world
                seed = request.seed if request.seed is not None else self.settings.seed
                self.rng = np.random.default_rng(seed)
                self.sensors = self._sensors(seed)
                self.measured = None
                self.seq.clear()
                self.published.clear()
                self.applied.clear()
                self._gt_cache = None
            return self.status()
        if op == "step":
            for start in range(0, request.n, 100):  # in slices: commands land between them
                with self.lock:
                    self.advance(min(100, request.n - start))
            return self.status()
        if op == "render":
            self.worker.submit(self.publish_frames)
            return self.status()
        if op in ("pause", "resume"):
            self.paused = op == "pause"
            return self.status()
        if op == "set_disturbance":
            with self.lock:
                amplitude = request.amplitude
                if self.world.is_hinge(request.joint):  # deg/s on the wire for hinges
                    amplitude = math.radians(amplitude)
                self.world.set_disturbance(request.joint, amplitude, request.frequency)
            return self.status()
        return self.status(False, f"unknown op {op}")

    def _support(self) -> tuple[list, list]:
        """The support graph, recomputed only when an object has moved by more than 1 cm."""
        w = self.world
        with self.lock:
            poses = np.array([w.data.xpos[w.model.body(n).id] for n in w.info.objects])
            data = copy.copy(w.data)
        cached = self._gt_cache
        if cached is not None and np.abs(poses - cached[0]).max(initial=0.0) < 0.01:
            return cached[1], cached[2]
        edges, closure = ground_truth.support_graph(w.model, data, w.info)
        self._gt_cache = (poses, edges, closure)
        return edges, closure

    def on_ground_truth(self, request: GroundTruthQuery | None) -> GroundTruth:
        request = request or GroundTruthQuery()
        camera = request.camera or self.cameras[0]
        edges, closure = self._support() if request.support else ([], [])
        labels, seg = [], None
        if request.segmentation:

            def segment(renderer: CameraRenderer):
                with self.lock:
                    return capture.segmentation(self.world, renderer, camera)

            labels, seg = self.worker.submit(segment)
        with self.lock:
            odom = self.sensors.odometry.T_world_odom() if self.sensors is not None else None
            return capture.ground_truth_message(
                self.world, edges, closure, camera, labels, seg, odom
            )

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.node.stop()
