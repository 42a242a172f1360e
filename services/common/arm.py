"""Arm kinematics on the robot's MJCF (pinocchio): the grasp frame's pose and Jacobian, damped
least-squares inverse kinematics, and the joint velocities of a Cartesian twist. Shared data,
like the robot files: the sim resolves Cartesian arm goals with it, the visual servo drives the
hand with it, and perception masks the robot's own body with the same model.

Poses are in the platform frame (the platform at the origin) unless a base pose is given: the
frame a reaching controller on a moving robot works in."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from services.common.robots import geom_position, robot_mjcf, site_mount

BASE_JOINT = "Composite_base_x"  # pinocchio's name for the platform's x, y, yaw
LIMIT_MARGIN = 0.3  # rad: a joint closer than this to the limit it moves toward is slowed
ARM_SEGMENTS = (
    "shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow", "forearm_roll", "wrist_pitch",
    "wrist_roll",
)  # fmt: skip


@dataclass(frozen=True)
class ArmSpec:
    """One arm of a robot: its seven joints (shoulder to wrist), gripper fingers, grasp site."""

    side: str
    joints: tuple[str, ...]
    fingers: tuple[str, ...]
    grasp_site: str
    marker: str  # the coloured ball on the wrist the cameras localise the hand by


def _armar3(side: str) -> ArmSpec:
    s = side[0]
    return ArmSpec(
        side,
        tuple(f"{s}_{j}" for j in ARM_SEGMENTS),
        (f"{s}_finger_a", f"{s}_finger_b"),
        f"{s}_grasp",
        f"{s}_marker",
    )


#: the arms of each robot (ARMAR-6's arms can follow)
ARMS: dict[str, dict[str, ArmSpec]] = {
    "armar3": {"left": _armar3("left"), "right": _armar3("right")},
    "armar6": {},
}


def arm_spec(robot: str, side: str) -> ArmSpec:
    arms = ARMS.get(robot, {})
    if side not in arms:
        raise KeyError(f"{robot} has no {side} arm (arms: {sorted(arms) or 'none'})")
    return arms[side]


def rotation_error(R_goal: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The rotation vector (world-aligned, rad) that turns R into R_goal: log(R_goal·Rᵀ)."""
    return pin.log3(R_goal @ R.T)


class ArmKinematics:
    """Forward kinematics, Jacobian and IK of one arm's grasp frame. ``q`` is a mapping of joint
    names (the arm's and any others, e.g. the hip that carries it) to positions."""

    def __init__(self, robot: str, side: str, mjcf: Path | None = None) -> None:
        mjcf = mjcf or robot_mjcf(robot)
        self.spec = arm_spec(robot, side)
        self.model = pin.buildModelFromMJCF(str(mjcf))
        self.data = self.model.createData()
        m = self.model
        body, T = site_mount(mjcf, self.spec.grasp_site)
        parent = m.frames[m.getFrameId(body)]
        self.frame = m.addFrame(
            pin.Frame(
                self.spec.grasp_site, parent.parentJoint, m.getFrameId(body),
                parent.placement * pin.SE3(T), pin.FrameType.OP_FRAME,
            )
        )  # fmt: skip
        body, p = geom_position(mjcf, self.spec.marker)
        parent = m.frames[m.getFrameId(body)]
        self.marker_frame = m.addFrame(
            pin.Frame(
                self.spec.marker, parent.parentJoint, m.getFrameId(body),
                parent.placement * pin.SE3(np.eye(3), p), pin.FrameType.OP_FRAME,
            )
        )  # fmt: skip
        self.data = m.createData()
        self.idx_q = {
            m.names[i]: m.joints[i].idx_q for i in range(1, m.njoints) if m.names[i] != BASE_JOINT
        }
        self.idx_v = {
            m.names[i]: m.joints[i].idx_v for i in range(1, m.njoints) if m.names[i] != BASE_JOINT
        }
        self.base_q = m.joints[m.getJointId(BASE_JOINT)].idx_q
        self.cols = np.array([m.joints[m.getJointId(n)].idx_v for n in self.spec.joints])
        qi = [self.idx_q[n] for n in self.spec.joints]
        self.lower = m.lowerPositionLimit[qi].copy()
        self.upper = m.upperPositionLimit[qi].copy()

    def configuration(
        self, q: Mapping[str, float], base: Sequence[float] = (0.0, 0.0, 0.0)
    ) -> np.ndarray:
        out = pin.neutral(self.model)
        out[self.base_q : self.base_q + 3] = base
        for n, v in q.items():
            if n in self.idx_q:
                out[self.idx_q[n]] = v
        return out

    def arm_q(self, q: Mapping[str, float]) -> np.ndarray:
        return np.array([q.get(n, 0.0) for n in self.spec.joints], float)

    def pose(self, q: Mapping[str, float], base: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """T of the grasp frame (4 × 4): z the approach direction, x the fingers' closing axis."""
        pin.framesForwardKinematics(self.model, self.data, self.configuration(q, base))
        return self.data.oMf[self.frame].homogeneous.copy()

    def marker(self, q: Mapping[str, float], base: Sequence[float] = (0.0, 0.0, 0.0)) -> np.ndarray:
        """Where the hand's marker (the ball the cameras localise the hand by) is."""
        pin.framesForwardKinematics(self.model, self.data, self.configuration(q, base))
        return self.data.oMf[self.marker_frame].translation.copy()

    def body_poses(
        self, q: Mapping[str, float], base: Sequence[float] = (0.0, 0.0, 0.0)
    ) -> dict[str, np.ndarray]:
        """T of every body frame of the model (name → 4 × 4)."""
        pin.framesForwardKinematics(self.model, self.data, self.configuration(q, base))
        m = self.model
        return {
            f.name: self.data.oMf[i].homogeneous.copy()
            for i, f in enumerate(m.frames)
            if f.type == pin.FrameType.BODY
        }

    def jacobian(self, q: Mapping[str, float]) -> tuple[np.ndarray, np.ndarray]:
        """(T of the grasp frame, its world-aligned 6 × 7 Jacobian over the arm's joints:
        linear velocity of the grasp point on top, angular below)."""
        x = self.configuration(q)
        pin.computeJointJacobians(self.model, self.data, x)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, self.frame, pin.LOCAL_WORLD_ALIGNED)
        return self.data.oMf[self.frame].homogeneous.copy(), J[:, self.cols]

    def carried(self, q: Mapping[str, float], qd: Mapping[str, float]) -> np.ndarray:
        """The grasp frame's twist (v, ω; world-aligned) that the joints carrying the arm (the
        hip, the torso) give it at their velocities ``qd``: what the arm must take off to hold
        the hand still while the body under it moves."""
        x = self.configuration(q)
        pin.computeJointJacobians(self.model, self.data, x)
        pin.updateFramePlacements(self.model, self.data)
        J = pin.getFrameJacobian(self.model, self.data, self.frame, pin.LOCAL_WORLD_ALIGNED)
        v = np.zeros(self.model.nv)
        for n, w in qd.items():
            if n in self.idx_v and n not in self.spec.joints and n not in self.spec.fingers:
                v[self.idx_v[n]] = w
        return J @ v

    def joint_velocities(
        self,
        q: Mapping[str, float],
        twist: np.ndarray,
        damping: float = 0.02,
        orientation_weight: float = 0.3,
    ) -> np.ndarray:
        """q̇ (7) for a wanted twist (v, ω) of the grasp frame: weighted damped least squares
        (orientation weighted below position: the hand must be where the cup is first), with a
        pull to mid-range in the null space and no joint driven past its limit."""
        _, J = self.jacobian(q)
        W = np.diag([1.0, 1.0, 1.0, *([orientation_weight] * 3)])
        A, b = W @ J, W @ np.asarray(twist, float)
        qa = self.arm_q(q)
        mid, span = (self.lower + self.upper) / 2, self.upper - self.lower
        # joints near a limit take part less and less the closer they are (weighted DLS), so
        # the others take over the task instead of the hand stalling at a clamped joint
        weight = np.ones(7)
        qd = np.zeros(7)
        for _ in range(2):
            Wq = np.diag(weight)
            pinv = Wq @ A.T @ np.linalg.inv(A @ Wq @ A.T + damping**2 * np.eye(6))
            qd = pinv @ b + (np.eye(7) - pinv @ A) @ (0.5 * (mid - qa) / span)
            toward = np.where(qd < 0, qa - self.lower, self.upper - qa)
            weight = np.clip(toward / LIMIT_MARGIN, 1e-3, 1.0)
            if (weight == 1.0).all():
                break
        qd = np.where((qa <= self.lower + 1e-3) & (qd < 0), 0.0, qd)
        return np.where((qa >= self.upper - 1e-3) & (qd > 0), 0.0, qd)

    def ik(
        self,
        goal: np.ndarray,
        q: Mapping[str, float],
        iterations: int = 300,
        tolerance: tuple[float, float] = (1e-3, np.radians(1.0)),
    ) -> tuple[np.ndarray, bool]:
        """Arm joint positions (7) that put the grasp frame at ``goal`` (4 × 4, platform
        frame), iterated from ``q``; and whether it got within ``tolerance`` (m, rad)."""
        cur = dict(q)
        ok = False
        for _ in range(iterations):
            T = self.pose(cur)
            e = np.concatenate([goal[:3, 3] - T[:3, 3], rotation_error(goal[:3, :3], T[:3, :3])])
            if np.linalg.norm(e[:3]) < tolerance[0] and np.linalg.norm(e[3:]) < tolerance[1]:
                ok = True
                break
            qa = self.arm_q(cur) + self.joint_velocities(cur, 0.5 * e)
            qa = np.clip(qa, self.lower, self.upper)
            cur.update(zip(self.spec.joints, qa, strict=True))
        return self.arm_q(cur), ok
