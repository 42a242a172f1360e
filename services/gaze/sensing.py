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
from numba import njit

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
    """b ← b + w·(ω_gyro − R_imuᵀ·J_ω·q̇ − b) on still samples, w = max(1/n, Δt/τ). The state
    lives in one array (``state``) that the stabiliser's compiled step updates in place."""

    def __init__(self, config: GyroBiasConfig | None = None) -> None:
        c = self.c = config or GyroBiasConfig()
        self.params = np.array([c.tau, c.still, c.motion, c.smooth, c.spike, c.settle], float)
        #: bias (3), smoothed residual (3), samples, still_s, last stamp, has smooth, has stamp
        self.state = np.zeros(11)

    @property
    def bias(self) -> np.ndarray:
        return self.state[0:3].copy()

    @property
    def samples(self) -> int:
        """Still samples taken."""
        return int(self.state[6])

    @property
    def still_s(self) -> float:
        """Still time taken, s."""
        return float(self.state[7])

    def update(self, gyro: np.ndarray, predicted: np.ndarray, stamp: float | None) -> bool:
        """Take one sample: ``gyro`` as read (IMU frame), ``predicted`` the forward model's
        angular velocity of the IMU (IMU frame). Returns whether it counted as still."""
        return bias_update(
            self.state, np.asarray(gyro, float), np.asarray(predicted, float),
            0.0 if stamp is None else float(stamp), stamp is not None, self.params,
        )  # fmt: skip


@njit(cache=True)
def bias_update(state, gyro, predicted, stamp, has_stamp, params) -> bool:
    """``GyroBias.update`` on its state array (compiled: the gaze's 1 kHz step calls it)."""
    tau, still, motion, smooth, spike, settle = params
    dt = 1e-3
    if has_stamp and state[10] > 0:
        dt = min(max(stamp - state[8], 0.0), 0.1)
    state[8], state[10] = stamp, 1.0 if has_stamp else 0.0
    residual = gyro - predicted
    a = min(1.0, dt / smooth)
    if state[9] > 0:
        state[3:6] += a * (residual - state[3:6])
    else:
        state[3:6] = residual
        state[9] = 1.0
    bias = state[0:3]
    moving = (
        np.sqrt(np.sum(predicted**2)) > still
        or (state[6] > 0 and np.sqrt(np.sum((residual - bias) ** 2)) > spike)
        or (state[6] >= settle and np.sqrt(np.sum((state[3:6] - bias) ** 2)) > motion)
    )
    if moving:
        return False
    state[6] += 1.0
    state[7] += dt
    w = max(1.0 / state[6], dt / tau)
    state[0:3] += w * (residual - bias)
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
