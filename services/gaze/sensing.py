"""What the gaze stabiliser makes of real sensors (issue 15): the gyro's bias, estimated while
the head is still, and measurements carried forward over their latency.

A MEMS gyro reads ω + b + n with a bias b of ~0.1 °/s that wanders slowly. The VOR takes the
gyro's rotation the forward model did not predict, ω_u = R·ω_gyro − J_ω·q̇: a bias is such a
rotation, so an unestimated one turns the eyes at b until the feedback stops them (a standing
fixation error of b/K). Whenever the forward model says the head is still (|J_ω·q̇| small) and
the gyro agrees (no unexplained rotation beyond the bias), the reading is the bias plus white
noise: ``GyroBias`` averages it (a running mean, then an exponential one of time constant τ),
the zero-velocity update of inertial navigation.

Joint states reach the controller a few milliseconds after they were measured (encoder bus,
transport, the 200 Hz state rate): ``predicted`` carries positions forward by their measured
velocities to the control step's instant."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

T = TypeVar("T")


@dataclass
class GyroBiasConfig:
    tau: float = 2.0  # s: the estimate's memory once it has that much still data
    #: rad/s: the forward model's head rotation below which the head counts as still
    still: float = math.radians(0.3)
    #: rad/s: a (20 ms averaged) reading further than this from the estimate is motion
    motion: float = math.radians(0.3)
    smooth: float = 0.02  # s: the averaging of the motion test
    #: rad/s: one reading this far from the estimate is motion (several σ of a MEMS gyro's
    #: per-sample noise at 1 kHz: 0.16-0.45 °/s)
    spike: float = math.radians(1.5)
    settle: int = 50  # samples before the averaged test applies (its average needs them)


class GyroBias:
    """b ← b + w·(ω_gyro − R_imuᵀ·J_ω·q̇ − b) on still samples, w = max(1/n, Δt/τ)."""

    def __init__(self, config: GyroBiasConfig | None = None) -> None:
        self.c = config or GyroBiasConfig()
        self.bias = np.zeros(3)
        self.samples = 0  # still samples taken
        self.still_s = 0.0  # still time taken, s
        self._smooth: np.ndarray | None = None
        self._stamp: float | None = None

    def update(self, gyro: np.ndarray, predicted: np.ndarray, stamp: float | None) -> bool:
        """Take one sample: ``gyro`` as read (IMU frame), ``predicted`` the forward model's
        angular velocity of the IMU (IMU frame). Returns whether it counted as still."""
        c = self.c
        dt = 1e-3 if stamp is None or self._stamp is None else min(max(stamp - self._stamp, 0), 0.1)
        self._stamp = stamp
        residual = np.asarray(gyro, float) - predicted
        a = min(1.0, dt / c.smooth)
        self._smooth = (
            residual if self._smooth is None else self._smooth + a * (residual - self._smooth)
        )
        moving = (
            float(np.linalg.norm(predicted)) > c.still
            or (self.samples > 0 and float(np.linalg.norm(residual - self.bias)) > c.spike)
            or (
                self.samples >= c.settle
                and float(np.linalg.norm(self._smooth - self.bias)) > c.motion
            )
        )
        if moving:
            return False
        self.samples += 1
        self.still_s += dt
        w = max(1.0 / self.samples, dt / c.tau)
        self.bias = self.bias + w * (residual - self.bias)
        return True


def predicted(
    position: Mapping[str, float], velocity: Mapping[str, float], horizon: float
) -> dict[str, float]:
    """Joint positions ``horizon`` s after they were measured, at their measured velocities."""
    if horizon <= 0.0:
        return dict(position)
    return {n: q + velocity.get(n, 0.0) * horizon for n, q in position.items()}


def nearest(samples: Sequence[tuple[float, T]], stamp: float, within: float) -> T | None:
    """The sample nearest ``stamp`` among (stamp, sample) pairs in arrival order, None without
    one within ``within`` s (scanned from the newest, up to the first older than that)."""
    best, gap = None, within
    for t, sample in reversed(samples):
        if abs(t - stamp) <= gap:
            best, gap = sample, abs(t - stamp)
        elif t < stamp:
            break
    return best
