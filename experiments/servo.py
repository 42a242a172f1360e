"""Position-based visual servoing of a hand to a grasp pose while the platform moves (thesis
5.4.2; Chaumette & Hutchinson 2006, PBVS; Vahrenkamp et al. 2008 on ARMAR-III).

The error is the pose of the grasp frame against the wanted one, e = (t, θu), both in the
platform frame; the hand is driven with the twist v = λ·e (saturated) plus the wanted pose's
own velocity (the object's motion relative to the moving platform), resolved into joint
velocities through the arm's Jacobian (``services.common.arm``). The hand's pose is the arm's
forward kinematics corrected by where the cameras see its marker, and the object's is where the
cameras localise it, so the kinematics' errors cancel (what visual servoing is for).

While the object is still out of reach, its pose is *projected* along the platform's motion to
where the arm will reach it (5.4.2: "the expected position at the time the robot would be able
to reach and grasp the object"), and the hand waits there; once it is in reach, the real pose."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.common.arm import ArmKinematics, rotation_error

PHASES = ("wait", "approach", "grasp", "close", "lift", "done")


@dataclass
class ServoConfig:
    gain: float = 3.0  # λ, 1/s
    max_linear: float = 0.3  # m/s
    max_angular: float = 1.0  # rad/s
    #: the grasp stored with the object: the grasp point's offset from its centre (m) and the
    #: approach direction's tilt below the platform's x axis (rad); the cup is symmetric about
    #: its axis, so only the approach direction matters, and the fingers close across it
    grasp_offset: tuple[float, float, float] = (0.0, 0.0, 0.01)
    approach_tilt: float = math.radians(20.0)
    pregrasp: float = 0.08  # m back along the approach axis before the final move
    #: where along the platform's x the arm reaches the object (m, platform frame)
    reach: tuple[float, float] = (0.05, 0.45)
    tolerance: tuple[float, float] = (0.012, math.radians(8.0))  # to close the fingers (m, rad)
    pregrasp_tolerance: float = 0.03  # m: near enough the pre-grasp pose to move in
    close_s: float = 0.6  # s the fingers take to close
    lift: float = 0.12  # m lifted after closing
    lift_s: float = 1.5  # s of lifting


def grasp_rotation(tilt: float) -> np.ndarray:
    """The grasp frame's rotation in the platform frame: z (approach) along x tilted ``tilt``
    down, x (the fingers' closing axis) along the platform's y."""
    z = np.array([math.cos(tilt), 0.0, -math.sin(tilt)])
    x = np.array([0.0, 1.0, 0.0])
    return np.column_stack([x, np.cross(z, x), z])


def project(
    position: np.ndarray, velocity: np.ndarray, reach: tuple[float, float]
) -> tuple[np.ndarray, bool]:
    """(where the object will be when the arm can reach it, whether it is in reach now): an
    object ahead of the reach moving towards it (``velocity``: its motion in the platform
    frame) is carried along that motion to the reach's front edge (5.4.2)."""
    p, v = np.asarray(position, float), np.asarray(velocity, float)
    lo, hi = reach
    if lo <= p[0] <= hi:
        return p.copy(), True
    if p[0] > hi and v[0] < -1e-6:
        return p + v * ((p[0] - hi) / -v[0]), False
    if p[0] < lo and v[0] > 1e-6:
        return p + v * ((lo - p[0]) / v[0]), False
    return np.array([min(max(p[0], lo), hi), p[1], p[2]]), False


@dataclass
class ServoStep:
    velocity: np.ndarray  # arm joint velocities (7)
    gripper: float  # 0 open … 1 closed
    phase: str
    error: tuple[float, float]  # (m, rad) of the hand against the pose it is driven to
    projected: bool


@dataclass
class GraspServo:
    """The grasp as a state machine: wait for the object, approach its (projected) pre-grasp
    pose, move in to the grasp pose once it is in reach, close, lift."""

    kinematics: ArmKinematics
    config: ServoConfig = field(default_factory=ServoConfig)
    phase: str = "wait"
    since: float = 0.0
    _lift_from: np.ndarray | None = None

    def _enter(self, phase: str, t: float) -> None:
        self.phase, self.since = phase, t

    def step(
        self,
        t: float,
        q: dict[str, float],
        hand_offset: np.ndarray,
        target: np.ndarray | None,
        target_velocity: np.ndarray,
        ready: bool = True,
        carried: np.ndarray | None = None,
    ) -> ServoStep:
        """One servo period. ``q``: the measured joints; ``hand_offset``: where the cameras see
        the hand minus where the kinematics put it (platform frame); ``target``: the object's
        position (platform frame) or None while it is not localised; ``target_velocity``: its
        motion in the platform frame (minus the platform's own); ``ready``: whether the object
        and the hand are localised well enough to move in (the pre-grasp pose is held until);
        ``carried``: the twist the body under the arm gives the hand (``ArmKinematics.carried``),
        taken off as a feed-forward."""
        c = self.config
        R = grasp_rotation(c.approach_tilt)
        T, _ = self.kinematics.jacobian(q)
        hand = T[:3, 3] + hand_offset
        if self.phase == "wait" and target is not None:
            self._enter("approach", t)
        if target is None or self.phase == "wait":
            return ServoStep(np.zeros(7), 0.0, self.phase, (math.nan, math.nan), False)
        goal, in_reach = project(np.asarray(target) + c.grasp_offset, target_velocity, c.reach)
        feedforward = np.asarray(target_velocity, float) if in_reach else np.zeros(3)
        gripper = 0.0
        if self.phase == "approach":
            goal = goal - c.pregrasp * R[:, 2]
        elif self.phase in ("close", "lift", "done"):
            gripper = 1.0
            if self.phase != "close":
                if self._lift_from is None:
                    self._lift_from = hand.copy()
                rise = (
                    c.lift
                    if self.phase == "done"
                    else min(1.0, (t - self.since) / c.lift_s) * c.lift
                )
                goal, feedforward = self._lift_from + np.array([0.0, 0.0, rise]), np.zeros(3)
        e_p = goal - hand
        e_r = rotation_error(R, T[:3, :3])
        error = (float(np.linalg.norm(e_p)), float(np.linalg.norm(e_r)))
        if self.phase == "approach" and in_reach and ready and error[0] < c.pregrasp_tolerance:
            self._enter("grasp", t)
        elif self.phase == "grasp" and error[0] < c.tolerance[0] and error[1] < c.tolerance[1]:
            self._enter("close", t)
        elif self.phase == "close" and t - self.since >= c.close_s:
            self._enter("lift", t)
        elif self.phase == "lift" and t - self.since >= c.lift_s:
            self._enter("done", t)
        v = c.gain * e_p
        n = np.linalg.norm(v)
        if n > c.max_linear:
            v *= c.max_linear / n
        w = c.gain * e_r
        n = np.linalg.norm(w)
        if n > c.max_angular:
            w *= c.max_angular / n
        twist = np.concatenate([v + feedforward, w])
        if carried is not None:
            twist = twist - carried
        qd = self.kinematics.joint_velocities(q, twist)
        return ServoStep(qd, gripper, self.phase, error, not in_reach)
