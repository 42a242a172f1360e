"""Odometry and view registration, each weighed by its error (thesis A.5 with an error model).

Registration (``registration.py``) measures the odometry's correction ``T_world_odom`` once per
registered frame; taking each measurement as it comes (the thesis's A.5) makes the map walk
with the registration's own errors: a frame-to-map fit off by a centimetre where the camera
turns fast is integrated at that pose, and the next frame is fitted to it. On a hand-held
Kinect v1 (redkitchen-a) with odometry that drifts 37 mm over 3.7 m, the registered pose ended
36 mm from the reference, 90 mm at worst: the registration's walk, not the drift.

Here the correction is a Kalman filter's state (an error-state filter on SE(3), or on the
ground plane's x, y and yaw for a ``"planar"`` platform): between registrations its covariance
grows with the motion the odometry integrated (Thrun et al. 2005, *Probabilistic Robotics*,
5.4: the odometry motion model's α₁…α₄, as a random walk in the distance travelled and the
angle turned), and each registration is a measurement with the registration's error (``σ`` of its
translation and rotation). The gain K = P (P + R)⁻¹ moves the correction part of the way to the
measurement: all of it after a long drive (P ≫ R), little after a few centimetres (P ≪ R).
The error is expressed at the camera (a turn about the camera's optical centre, then a shift),
so that the odometry's error, which it incurs where the camera is, needs no lever arm; the
covariance is carried to the next camera position with the lever arm a turn there has
(``transport``). ``mahalanobis`` is how far a measurement is from what the filter expected:
a registration neither error explains (beyond χ² 99.9 %) is refused.

The memory weighs registrations only where the odometry's error is given
(``AVS_SCENE_MEMORY_ODOMETRY_NOISE``, ``RegistrationConfig.odometry_noise``): a filter that
believes an odometry better than it is lags its drift (a platform drifting 1.2 cm a view while
only the head turns, ``tests/scene_memory/test_registration.py``). On redkitchen-a with the
issue's drift, in process (``tests/scene_memory/test_correction_filter.py``), 2 % of the motion
brought the held pose's error, median over the frames, from 42 to 10 mm (planar; at most 90 →
24 mm); a weighed still run (no drift) from 43 to 17 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np


@dataclass(frozen=True)
class OdometryNoise:
    """The odometry's error (Thrun et al. 2005, Table 5.6's α₁…α₄): between two registrations
    it grows in proportion to the distance travelled and the angle turned (a scale error, the
    same whether the motion came in one increment or in ten), and it is independent from one
    registration interval to the next. Each field is σ per unit of motion. 2 %: wheel
    odometry's 1-2 % (the sim's platform drifts 1.5 % of the distance,
    ``SensorSpec.odometry_scale_error``). The camera's motion includes the head's, which the
    odometry does not integrate: an overestimate, on the side of taking registrations as they
    come."""

    #: the turn's σ after one radian turned (α₁, rad) and after one metre travelled (α₂, rad)
    rad_per_rad: float = 0.02
    rad_per_m: float = 0.01
    #: the position's σ after one metre travelled (α₃, m) and after one radian turned (α₄, m)
    m_per_m: float = 0.02
    m_per_rad: float = 0.005

    @classmethod
    def share(cls, a: float) -> OdometryNoise:
        """``a`` of the distance and of the turn (α₁ = α₃ = a), less across (α₂ = a/2,
        α₄ = a/4)."""
        return cls(rad_per_rad=a, rad_per_m=a / 2, m_per_m=a, m_per_rad=a / 4)


@dataclass(frozen=True)
class RegistrationNoise:
    """σ of a registration's error, translation (m) and rotation (degrees). On a Kinect v1
    (redkitchen-a), a frame at its reference pose registered against the frames before it at
    theirs moves a median 9 mm, up to 47 mm where the camera turns fast
    (``benchmarks/real_data.py``'s ``reference_offset_mm_*``)."""

    m: float = 0.02
    deg: float = 1.0


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _log_rotation(R: np.ndarray) -> np.ndarray:
    """The rotation vector of ``R`` (axis × angle, rad)."""
    cos = max(-1.0, min(1.0, (float(np.trace(R)) - 1.0) / 2.0))
    angle = math.acos(cos)
    if angle < 1e-9:
        return np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]]) / 2.0
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return w * angle / (2.0 * math.sin(angle))


def _exp_rotation(w: np.ndarray) -> np.ndarray:
    """Rodrigues: the rotation of the rotation vector ``w``."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + _skew(w)
    K = _skew(w / angle)
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


class CorrectionFilter:
    """The correction ``T`` (T_world_odom) and its error's covariance ``P`` at the camera.

    ``dof`` "planar": the error is (x, y, yaw); "full": (x, y, z, rx, ry, rz), rotations
    about the camera's optical centre. It starts at ``T`` (default identity: the first frame
    defines the map) with ``P`` = 0."""

    def __init__(
        self,
        dof: Literal["planar", "full"] = "planar",
        odometry: OdometryNoise | None = None,
        registration: RegistrationNoise | None = None,
        T: np.ndarray | None = None,
    ) -> None:
        self.dof = dof
        self.odometry = odometry or OdometryNoise()
        self.registration = registration or RegistrationNoise()
        n = 3 if dof == "planar" else 6
        self.T = np.eye(4) if T is None else np.asarray(T, float).copy()
        self.P = np.zeros((n, n))
        #: the odometry pose (T_odom_camera) the covariance was last brought to
        self.T_odom: np.ndarray | None = None
        #: the distance (m) and turn (rad) the odometry integrated since the last update
        self.motion = (0.0, 0.0)

    @property
    def n(self) -> int:
        return self.P.shape[0]

    def _pivot(self, T_odom: np.ndarray) -> np.ndarray:
        return (self.T @ T_odom)[:3, 3]

    def transport(self, T_odom: np.ndarray) -> None:
        """Carry ``P`` from the last camera to this one: a turn ω about the old centre p₁ is
        the same turn about the new centre p₂ and a shift (R − I)(p₂ − p₁) ≈ ω × (p₂ − p₁)."""
        if self.T_odom is None:
            return
        d = self._pivot(T_odom) - self._pivot(self.T_odom)  # p₂ − p₁
        if self.dof == "planar":
            A = np.eye(3)
            A[0, 2], A[1, 2] = -d[1], d[0]
        else:
            A = np.eye(6)
            A[:3, 3:] = -_skew(d)
        self.P = A @ self.P @ A.T

    def predict(self, T_odom: np.ndarray) -> None:
        """The odometry moved the camera from the last pose to ``T_odom`` (T_odom_camera): the
        covariance is carried there and grows by the motion model."""
        if self.T_odom is None:
            self.T_odom = np.asarray(T_odom, float).copy()
            return
        moved = float(np.linalg.norm(T_odom[:3, 3] - self.T_odom[:3, 3]))
        turned = float(np.linalg.norm(_log_rotation(self.T_odom[:3, :3].T @ T_odom[:3, :3])))
        self.transport(T_odom)
        before = self._sigmas()
        self.motion = (self.motion[0] + moved, self.motion[1] + turned)
        (p1, r1), (p0, r0) = self._sigmas(), before
        q = [p1**2 - p0**2] * (2 if self.dof == "planar" else 3) + [r1**2 - r0**2] * (
            1 if self.dof == "planar" else 3
        )
        self.P = self.P + np.diag(q)
        self.T_odom = np.asarray(T_odom, float).copy()

    def _sigmas(self) -> tuple[float, float]:
        """σ of the position and of the turn the odometry gained since the last update."""
        o, (moved, turned) = self.odometry, self.motion
        return (
            o.m_per_m * moved + o.m_per_rad * turned,
            o.rad_per_rad * turned + o.rad_per_m * moved,
        )

    def R(self) -> np.ndarray:
        r = self.registration
        rot = math.radians(r.deg) ** 2
        planar = self.dof == "planar"
        return np.diag([r.m**2] * (2 if planar else 3) + [rot] * (1 if planar else 3))

    def innovation(self, T_measured: np.ndarray) -> np.ndarray:
        """The measurement's difference from the state, at the camera: Δ = T_measured · T⁻¹
        as a turn about the camera's centre p and the shift R p + t − p."""
        assert self.T_odom is not None
        D = T_measured @ np.linalg.inv(self.T)
        p = self._pivot(self.T_odom)
        shift = D[:3, :3] @ p + D[:3, 3] - p
        w = _log_rotation(D[:3, :3])
        if self.dof == "planar":
            return np.array([shift[0], shift[1], w[2]])
        return np.concatenate([shift, w])

    def mahalanobis(self, T_measured: np.ndarray) -> float:
        """d² of the measurement against the state and both errors (χ² with ``n`` dof)."""
        v = self.innovation(T_measured)
        return float(v @ np.linalg.solve(self.P + self.R(), v))

    def update(self, T_measured: np.ndarray) -> np.ndarray:
        """Weigh a registration's T_world_odom against the state; the new state."""
        v = self.innovation(T_measured)
        S = self.P + self.R()
        K = self.P @ np.linalg.inv(S)
        step = K @ v
        p = self._pivot(self.T_odom)
        if self.dof == "planar":
            shift, w = np.array([step[0], step[1], 0.0]), np.array([0.0, 0.0, step[2]])
        else:
            shift, w = step[:3], step[3:]
        Rw = _exp_rotation(w)
        D = np.eye(4)
        D[:3, :3] = Rw
        D[:3, 3] = p - Rw @ p + shift
        self.T = D @ self.T
        self.P = (np.eye(self.n) - K) @ self.P
        self.P = (self.P + self.P.T) / 2
        self.motion = (0.0, 0.0)
        return self.T.copy()
