"""The simulated robot in its scene: physics, the base and joint controllers, sensor readouts.

Pure core: MuJoCo and numpy, no transport. ``World.step()`` advances one physics step of
``timestep`` seconds after applying the commands:

- the platform follows a ``BaseGoal`` (straight or along waypoints) or a ``BaseVelocity``, never
  faster than vel_lin / vel_rot and never accelerating harder than acc_lin / acc_rot;
- every other joint follows a reference that position commands move at the joint's speed limit
  and velocity commands integrate, clamped to the joint's range, with the reference velocity
  fed forward (a position and a velocity servo per joint in the MJCF);
- a disturbance drives one joint with q̇ = A·cos(2πft) (thesis 5.4).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from services.common.arm import ArmKinematics
from services.sim.robots import BASE_JOINTS, RobotInfo
from services.sim.scene import (
    ROBOT_PREFIX,
    check_start_overlaps,
    load_world_model,
    robot_joint_names,
)

#: the two joints that aim each robot's main camera: (pan, tilt)
AIM_JOINTS = {"armar6": ("neck_yaw", "neck_pitch"), "armar3": ("neck_yaw", "neck_upper_pitch")}
#: seconds the scene settles at reset before time starts
SETTLE_S = 0.3
#: MuJoCo's sleep (islands) as an ``opt.enableflags`` bit
SLEEP = int(mujoco.mjtEnableBit.mjENBL_SLEEP)
#: a goal is reached within these tolerances (m, rad)
GOAL_TOLERANCE = (0.005, math.radians(0.3))
#: platform position gain when approaching a goal (1/s)
BASE_GAIN = 3.0


def wrap(angle: float) -> float:
    """Angle in (-π, π] (thesis Eq. 4.7)."""
    return math.atan2(math.sin(angle), math.cos(angle))


@dataclass
class JointServo:
    name: str
    qpos: int
    dof: int
    lower: float
    upper: float
    pos_act: int
    vel_act: int
    speed: float
    q_ref: float = 0.0
    v_ref: float = 0.0
    target: float | None = None  # position command being moved to
    velocity: float = 0.0  # velocity command
    velocity_until: float = -1.0

    def clamp(self, q: float) -> float:
        return min(max(q, self.lower), self.upper)


@dataclass
class Disturbance:
    joint: str
    amplitude: float  # rad/s (hinge) or m/s (slide)
    frequency: float  # Hz
    start: float


@dataclass
class BaseCommand:
    goal_id: str = ""
    waypoints: list[tuple[float, float, float]] = field(default_factory=list)
    index: int = 0
    velocity: tuple[float, float, float] | None = None  # base frame
    velocity_until: float = -1.0
    status: str = "idle"


class World:
    """One robot in one scene. Not thread-safe: the caller serialises access."""

    def __init__(
        self,
        scene: str | Path,
        robot: RobotInfo,
        *,
        timestep: float = 0.001,
        head_velocity_timeout: float = 0.1,
        sleep: bool = True,
    ) -> None:
        """``sleep``: objects at rest sleep (MuJoCo's islands, ``mjENBL_SLEEP``): a step skips
        their dynamics and contacts until an awake body touches them (the robot, actuated,
        never sleeps; the reset's settle runs awake). On ``kitchen`` a step costs 12 µs instead
        of 44, at the IMU's 1 kHz."""
        self.robot = robot
        self.model, self.info = load_world_model(scene, robot, timestep=timestep)
        if sleep:
            self.model.opt.enableflags |= SLEEP
        self.data = mujoco.MjData(self.model)
        self.timestep = timestep
        self.head_velocity_timeout = head_velocity_timeout
        m = self.model
        self._base_qpos = [m.joint(ROBOT_PREFIX + n).qposadr[0] for n in BASE_JOINTS]
        self._base_dof = [m.joint(ROBOT_PREFIX + n).dofadr[0] for n in BASE_JOINTS]
        self._base_act = [m.actuator(ROBOT_PREFIX + n).id for n in BASE_JOINTS]
        self.joint_names = [n for n in robot_joint_names(m) if n not in BASE_JOINTS]
        self.servos: dict[str, JointServo] = {}
        for n in self.joint_names:
            j = m.joint(ROBOT_PREFIX + n)
            lower, upper = j.range if j.limited[0] else (-math.inf, math.inf)
            self.servos[n] = JointServo(
                name=n,
                qpos=int(j.qposadr[0]),
                dof=int(j.dofadr[0]),
                lower=float(lower),
                upper=float(upper),
                pos_act=m.actuator(ROBOT_PREFIX + n).id,
                vel_act=m.actuator(ROBOT_PREFIX + n + "_v").id,
                speed=robot.joint_speed.get(n, 1.0),
            )
        sensor = {
            name: m.sensor(ROBOT_PREFIX + name) for name in ("imu_gyro", "imu_accel", "imu_quat")
        }
        self._imu = {k: (int(s.adr[0]), int(s.dim[0])) for k, s in sensor.items()}
        self._imu_site = m.site(ROBOT_PREFIX + "imu").id
        self._head_body = int(m.site_bodyid[self._imu_site])
        self.cameras = {c.name: m.camera(ROBOT_PREFIX + c.name).id for c in robot.cameras}
        self.base = BaseCommand()
        self.disturbance: Disturbance | None = None
        self._arms: dict[str, ArmKinematics] = {}
        self._fk_data: mujoco.MjData | None = None  # T_world_camera_at's scratch state
        self._v_cmd = np.zeros(3)  # world vx, vy, yaw rate being commanded
        self._hold = np.zeros(3)
        self.steps = 0
        self.reset()

    # -- life cycle ---------------------------------------------------------------------------

    def reset(self) -> None:
        """Robot at robot_start in its home pose, objects settled, time zero."""
        m, d = self.model, self.data
        mujoco.mj_resetData(m, d)
        x, y, yaw = self.info.robot_start
        for adr, v in zip(self._base_qpos, (x, y, yaw), strict=True):
            d.qpos[adr] = v
        for s in self.servos.values():
            s.q_ref = s.clamp(self.robot.home.get(s.name, 0.0))
            s.v_ref, s.target, s.velocity, s.velocity_until = 0.0, None, 0.0, -1.0
            d.qpos[s.qpos] = s.q_ref
        check_start_overlaps(self.info.path, m, d)
        self.base = BaseCommand()
        self.disturbance = None
        self._v_cmd[:] = 0.0
        self._hold[:] = (x, y, yaw)
        # the settle awake: an object that slowed below the sleep tolerance on its way down
        # would sleep short of where it comes to rest (by up to 0.1 mm)
        flags = m.opt.enableflags
        m.opt.enableflags &= ~SLEEP
        for _ in range(int(SETTLE_S / self.timestep)):
            self.step()
        m.opt.enableflags = flags
        d.time = 0.0
        self.steps = 0

    @property
    def time(self) -> float:
        return float(self.data.time)

    def step(self, n: int = 1) -> None:
        for _ in range(n):
            self._control()
            mujoco.mj_step(self.model, self.data)
            self.steps += 1

    # -- commands -----------------------------------------------------------------------------

    def set_base_goal(
        self, x: float, y: float, yaw: float, path: np.ndarray | None = None, goal_id: str = ""
    ) -> None:
        waypoints = [tuple(map(float, p)) for p in (path if path is not None else [])]
        self.base = BaseCommand(
            goal_id=goal_id, waypoints=[*waypoints, (x, y, yaw)], status="moving"
        )

    def set_base_velocity(self, v_x: float, v_y: float, v_yaw: float, timeout: float) -> None:
        """Velocity in the base frame; it stops after ``timeout`` seconds without a newer one."""
        self.base = BaseCommand(
            velocity=(v_x, v_y, v_yaw), velocity_until=self.time + timeout, status="moving"
        )

    def command_joints(self, names: list[str], mode: str, values: np.ndarray) -> list[str]:
        """Position or velocity commands for named joints; returns the names it did not know."""
        unknown = []
        for name, value in zip(names, values, strict=True):
            s = self.servos.get(name)
            if s is None:
                unknown.append(name)
                continue
            if mode == "position":
                s.target, s.velocity, s.velocity_until = s.clamp(float(value)), 0.0, -1.0
            else:
                s.target = None
                s.velocity = float(value)
                s.velocity_until = self.time + self.head_velocity_timeout
        return unknown

    def command_arm(
        self,
        side: str,
        mode: str,
        names: list[str] | None = None,
        values: np.ndarray | None = None,
        goal: np.ndarray | None = None,
        gripper: float | None = None,
    ) -> list[str]:
        """An arm command (``schemas.ArmCommand``): joint velocities or positions of that
        arm's joints, a Cartesian goal of its grasp frame (T_platform_grasp, resolved by
        inverse kinematics from where the arm is), and/or the gripper (0 open … 1 closed).
        Returns the joint names it refused (unknown, or not of that arm)."""
        kin = self._arm(side)
        spec = kin.spec
        refused: list[str] = []
        if mode in ("velocity", "position") and names is not None and values is not None:
            mine = [n in spec.joints for n in names]
            refused = [n for n, ok in zip(names, mine, strict=True) if not ok]
            keep = [n for n, ok in zip(names, mine, strict=True) if ok]
            vals = np.asarray(values, float)[np.array(mine, bool)]
            self.command_joints(keep, mode, vals)
        elif mode == "cartesian" and goal is not None:
            names_, q, _ = self.joint_state()
            solution, _ = kin.ik(np.asarray(goal, float), dict(zip(names_, q, strict=True)))
            self.command_joints(list(spec.joints), "position", solution)
        if gripper is not None:
            closed = [self.servos[f].upper for f in spec.fingers]
            self.command_joints(list(spec.fingers), "position", float(gripper) * np.array(closed))
        return refused

    def _arm(self, side: str) -> ArmKinematics:
        """The kinematics of one arm (built on first use; KeyError for an arm it lacks)."""
        if side not in self._arms:
            self._arms[side] = ArmKinematics(self.robot.name, side, self.robot.mjcf)
        return self._arms[side]

    def is_hinge(self, joint: str) -> bool:
        if joint not in self.servos:
            raise KeyError(f"{self.robot.name} has no joint {joint!r} (has {self.joint_names})")
        j = self.model.joint(ROBOT_PREFIX + joint).id
        return self.model.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE

    def set_disturbance(self, joint: str, amplitude: float, frequency: float) -> None:
        """q̇ = amplitude·cos(2π·frequency·t) on ``joint`` from now; amplitude 0 stops it."""
        if joint not in self.servos:
            raise KeyError(f"{self.robot.name} has no joint {joint!r} (has {self.joint_names})")
        self.disturbance = (
            Disturbance(joint, amplitude, frequency, self.time) if amplitude != 0 else None
        )
        self.servos[joint].target = None

    # -- control ------------------------------------------------------------------------------

    def _control(self) -> None:
        """The servos' references and the platform's velocity command for the next step (plain
        floats: this runs at 1 kHz, where numpy's per-call cost would dominate)."""
        dt, t, ctrl = self.timestep, self.time, self.data.ctrl
        dist = self.disturbance
        for s in self.servos.values():
            q_prev = s.q_ref
            if dist is not None and dist.joint == s.name:
                v = dist.amplitude * math.cos(2 * math.pi * dist.frequency * (t - dist.start))
                s.q_ref = s.clamp(s.q_ref + v * dt)
            elif s.target is not None:
                step = s.speed * dt
                s.q_ref += min(max(s.target - s.q_ref, -step), step)
            elif t < s.velocity_until:
                s.q_ref = s.clamp(s.q_ref + s.velocity * dt)
            s.v_ref = (s.q_ref - q_prev) / dt
            ctrl[s.pos_act] = s.q_ref
            ctrl[s.vel_act] = s.v_ref
        self._base_control()

    def _base_control(self) -> None:
        r, b, dt, qpos = self.robot, self.base, self.timestep, self.data.qpos
        x, y, yaw = (float(qpos[a]) for a in self._base_qpos)
        if b.velocity is not None:
            if self.time < b.velocity_until:
                vx, vy, w = b.velocity
                c, s = math.cos(yaw), math.sin(yaw)
                desired = [c * vx - s * vy, s * vx + c * vy, w]
            else:  # timed out: brake at the acceleration limits, then hold where it stopped
                desired = [0.0, 0.0, 0.0]
                if not self._v_cmd.any():
                    self.base = BaseCommand(status="idle")
                    self._hold[:] = (x, y, yaw)
        else:
            if b.waypoints:
                tx, ty, tyaw = b.waypoints[b.index]
                last = b.index == len(b.waypoints) - 1
            else:
                (tx, ty, tyaw), last = self._hold.tolist(), True
            ex, ey, eyaw = tx - x, ty - y, wrap(tyaw - yaw)
            dist = math.hypot(ex, ey)
            if not last and dist < 0.1:
                b.index += 1
                return self._base_control()
            speed = (
                r.vel_lin
                if not last
                else min(r.vel_lin, BASE_GAIN * dist, 0.95 * math.sqrt(2 * r.acc_lin * dist))
            )
            turn = min(
                r.vel_rot, BASE_GAIN * abs(eyaw), 0.95 * math.sqrt(2 * r.acc_rot * abs(eyaw))
            )
            desired = [
                speed * ex / dist if dist > 1e-9 else 0.0,
                speed * ey / dist if dist > 1e-9 else 0.0,
                math.copysign(turn, eyaw),
            ]
            if b.waypoints and last and dist < GOAL_TOLERANCE[0] and abs(eyaw) < GOAL_TOLERANCE[1]:
                self.base = BaseCommand(goal_id=b.goal_id, status="reached")
                self._hold[:] = (tx, ty, tyaw)
        # never faster than the limits, never accelerating harder than the limits
        lin = math.hypot(desired[0], desired[1])
        if lin > r.vel_lin:
            desired[0] *= r.vel_lin / lin
            desired[1] *= r.vel_lin / lin
        desired[2] = min(max(desired[2], -r.vel_rot), r.vel_rot)
        v_cmd = self._v_cmd.tolist()
        dv = [d - v for d, v in zip(desired, v_cmd, strict=True)]
        dv_lin = math.hypot(dv[0], dv[1])
        if dv_lin > r.acc_lin * dt:
            dv[0] *= r.acc_lin * dt / dv_lin
            dv[1] *= r.acc_lin * dt / dv_lin
        dv[2] = min(max(dv[2], -r.acc_rot * dt), r.acc_rot * dt)
        ctrl = self.data.ctrl
        for i, act in enumerate(self._base_act):
            v = v_cmd[i] + dv[i]
            self._v_cmd[i] = v
            ctrl[act] = v

    # -- placing the robot (tools and tests: a teleport, not a motion) ----------------------

    def place(self, base: tuple[float, float, float] | None = None, **joints: float) -> None:
        """Put the platform at (x, y, yaw) and joints at positions (clamped), at rest."""
        d = self.data
        if base is not None:
            for adr, v in zip(self._base_qpos, base, strict=True):
                d.qpos[adr] = v
            self._hold[:] = base
            self.base = BaseCommand()
            self._v_cmd[:] = 0.0
        for name, value in joints.items():
            s = self.servos[name]
            s.q_ref = s.clamp(value)
            s.target, s.velocity_until = None, -1.0
            d.qpos[s.qpos] = s.q_ref
        d.qvel[:] = 0.0
        mujoco.mj_forward(self.model, d)

    def look_at(self, target: np.ndarray, camera: str | None = None) -> float:
        """Turn the head so the camera's optical axis passes through ``target`` (world), as
        far as the joints' ranges allow; returns the angle (rad) left between the axis and
        the direction to the target."""
        camera = camera or self.robot.default_cameras[0]
        pan, tilt = AIM_JOINTS[self.robot.name]
        for _ in range(8):
            T = self.T_world_camera(camera)
            t = T[:3, :3].T @ (np.asarray(target) - T[:3, 3])  # optical frame: x right, y down
            dpan, dtilt = math.atan2(-t[0], t[2]), math.atan2(t[1], math.hypot(t[0], t[2]))
            if abs(dpan) < 1e-5 and abs(dtilt) < 1e-5:
                break
            q = dict(zip(*self.joint_state()[:2], strict=True))
            self.place(**{pan: q[pan] + dpan, tilt: q[tilt] + dtilt})
        T = self.T_world_camera(camera)
        to = np.asarray(target, float) - T[:3, 3]
        return math.acos(min(1.0, float(T[:3, 2] @ to / max(np.linalg.norm(to), 1e-9))))

    def face(self, target: np.ndarray, camera: str | None = None) -> None:
        """Look at ``target``; where the neck cannot turn that far, first turn the platform in
        place toward it (a start that faces away still sees the scene)."""
        if self.look_at(target, camera) > math.radians(1.0):
            x, y, _ = self.base_pose()[:3]
            self.place(base=(x, y, math.atan2(target[1] - y, target[0] - x)))
            self.look_at(target, camera)

    # -- readouts -----------------------------------------------------------------------------

    def imu(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(gyro rad/s, accelerometer m/s² specific force, orientation wxyz) of the head IMU."""
        sd = self.data.sensordata
        out = []
        for key in ("imu_gyro", "imu_accel", "imu_quat"):
            adr, dim = self._imu[key]
            out.append(np.array(sd[adr : adr + dim], dtype=np.float64))
        return out[0], out[1], out[2]

    def head_angular_velocity(self) -> np.ndarray:
        """Angular velocity of the IMU's body in the IMU frame (the truth the gyro measures)."""
        v = np.zeros(6)
        mujoco.mj_objectVelocity(
            self.model, self.data, mujoco.mjtObj.mjOBJ_SITE, self._imu_site, v, 1
        )
        return v[:3]

    def joint_state(self) -> tuple[list[str], np.ndarray, np.ndarray]:
        q = np.array([self.data.qpos[s.qpos] for s in self.servos.values()])
        qd = np.array([self.data.qvel[s.dof] for s in self.servos.values()])
        return list(self.servos), q, qd

    def base_pose(self) -> tuple[float, float, float, float, float, float]:
        """x, y, yaw (wrapped) and the world-frame velocities vx, vy, yaw rate."""
        x, y, yaw = (float(self.data.qpos[a]) for a in self._base_qpos)
        vx, vy, w = (float(self.data.qvel[a]) for a in self._base_dof)
        return x, y, wrap(yaw), vx, vy, w

    def T_world_camera(self, camera: str) -> np.ndarray:
        """Pose of the camera's optical frame (x right, y down, z forward) in the world."""
        return _optical_pose(self.data, self.cameras[camera])

    def T_world_camera_at(
        self,
        camera: str,
        base: tuple[float, float, float],
        joints: tuple[list[str], np.ndarray],
    ) -> np.ndarray:
        """Forward kinematics of the camera with the platform at ``base`` (x, y, yaw) and the
        named ``joints`` at their positions (the others where they are): the pose the robot
        believes its camera has when ``base`` is the odometry's and ``joints`` the encoders'.
        The world's own state is untouched (a scratch copy is moved)."""
        if self._fk_data is None:
            self._fk_data = mujoco.MjData(self.model)
        d = self._fk_data
        d.qpos[:] = self.data.qpos
        for adr, v in zip(self._base_qpos, base, strict=True):
            d.qpos[adr] = v
        for name, v in zip(*joints, strict=True):
            d.qpos[self.servos[name].qpos] = v
        mujoco.mj_kinematics(self.model, d)
        mujoco.mj_comPos(self.model, d)
        mujoco.mj_camlight(self.model, d)
        return _optical_pose(d, self.cameras[camera])


def look_target(world: World) -> np.ndarray:
    """Where a first view looks: the roi's centre, or the centre of the scene's objects."""
    if world.info.roi is not None:
        return (world.info.roi[0] + world.info.roi[1]) / 2
    return np.mean([world.data.xpos[world.model.body(n).id] for n in world.info.objects], axis=0)


def _optical_pose(data: mujoco.MjData, camera_id: int) -> np.ndarray:
    """The optical frame (x right, y down, z forward) of camera ``camera_id`` in ``data``'s
    world (MuJoCo's camera looks along −z with y up)."""
    T = np.eye(4)
    T[:3, :3] = data.cam_xmat[camera_id].reshape(3, 3) @ np.diag([1.0, -1.0, -1.0])
    T[:3, 3] = data.cam_xpos[camera_id]
    return T
