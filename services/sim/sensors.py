"""Sensor models: what a real robot's IMU, joint encoders, camera and platform odometry tell it,
instead of the simulator's truth (issue 15; thesis A.5 registers views because odometry drifts).

Each model is pure (numpy, a ``Generator``), driven by the sim node:

- ``ImuModel``: gyro white noise (noise density) plus a bias that starts random and random-walks,
  accelerometer white noise, and jitter on each sample's timestamp;
- ``EncoderModel``: joint positions quantised to the encoder's resolution after additive noise,
  velocities with noise;
- ``Delay``: a latency line (joint states and frames are published ``latency`` after they were
  measured, stamped with the measurement time);
- ``Odometry``: the platform pose the robot *believes*, integrated from the true motion's
  increments with a scale error (drift proportional to distance), a yaw error proportional to
  rotation and random walks in both.

The parameters (``SensorSpec``) are per robot; their defaults and sources are documented field by
field.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")

G = 9.80665  # m/s² per g


@dataclass(frozen=True)
class SensorSpec:
    """A robot's sensor parameters (SI units; the source values in the comments)."""

    #: gyro white noise, rad/s/√Hz: 0.005 °/s/√Hz, a good MEMS gyro (Bosch BMI088 datasheet:
    #: 0.014 °/s/√Hz; ADIS16470: 0.0035 °/s/√Hz)
    gyro_noise_density: float = math.radians(0.005)
    #: the gyro's bias at start, σ rad/s: 0.1 °/s, a calibrated MEMS gyro's residual turn-on bias
    gyro_bias_sigma: float = math.radians(0.1)
    #: the bias's random walk, rad/s/√s: 4e-4 °/s/√s, so it wanders ~0.003 °/s a minute (MEMS
    #: bias instability: 2–10 °/h, i.e. 0.0006–0.003 °/s)
    gyro_bias_walk: float = math.radians(4e-4)
    #: accelerometer white noise, m/s²/√Hz: 150 µg/√Hz (BMI088: 175 µg/√Hz)
    accel_noise_density: float = 150e-6 * G
    #: σ of an IMU sample's timestamp error, s (its own clock against the sample's instant)
    imu_stamp_jitter: float = 20e-6
    #: joint encoder resolution, rad: a 14-bit absolute encoder, 2π/2¹⁴
    encoder_resolution: float = 2 * math.pi / 2**14
    #: joint position noise before quantisation, σ rad
    encoder_noise: float = 1e-4
    #: joint velocity noise, σ rad/s (the motor controller's filtered velocity)
    encoder_velocity_noise: float = 2e-3
    #: measurement → publication of a joint state, s: one 1 kHz bus cycle plus transport
    joint_latency: float = 0.002
    #: capture → publication of a camera frame, s: structured-light cameras deliver 30–50 ms
    #: after exposure (Primesense Carmine / Kinect v1)
    frame_latency: float = 0.040
    #: odometry's scale error: 1.5 % of the distance driven (wheel radius and slip; 1–2 % is
    #: typical of mecanum/omni platforms)
    odometry_scale_error: float = 0.015
    #: odometry's yaw error per radian turned: 1° per full turn
    odometry_yaw_error: float = 1.0 / 360.0
    #: random walk of the odometry's position, m/√m driven
    odometry_walk: float = 0.005
    #: random walk of the odometry's heading, rad/√m driven
    odometry_yaw_walk: float = math.radians(0.1)


class ImuModel:
    """Gyro: ω + b + n, with b(0) ~ N(0, bias_sigma²) and b a random walk, n white with the
    noise density; accelerometer: a + n. One ``measure`` per sample, ``dt`` apart."""

    def __init__(self, spec: SensorSpec, rng: np.random.Generator) -> None:
        self.spec, self.rng = spec, rng
        self.bias = rng.standard_normal(3) * spec.gyro_bias_sigma

    def measure(
        self, gyro: np.ndarray, accel: np.ndarray, dt: float
    ) -> tuple[np.ndarray, np.ndarray]:
        s = self.spec
        n = self.rng.standard_normal(9)
        self.bias = self.bias + n[:3] * (s.gyro_bias_walk * math.sqrt(dt))
        white = 1.0 / math.sqrt(dt)  # σ of a sample = density / √Δt (Kalibr's convention)
        return (
            gyro + self.bias + n[3:6] * (s.gyro_noise_density * white),
            accel + n[6:9] * (s.accel_noise_density * white),
        )

    def stamp(self, t: float) -> float:
        return t + float(self.rng.standard_normal()) * self.spec.imu_stamp_jitter


class EncoderModel:
    """Positions: round((q + n)/resolution)·resolution; velocities: q̇ + n."""

    def __init__(self, spec: SensorSpec, rng: np.random.Generator) -> None:
        self.spec, self.rng = spec, rng

    def measure(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s, n = self.spec, self.rng.standard_normal(2 * len(q))
        res = s.encoder_resolution
        q_meas = np.round((q + n[: len(q)] * s.encoder_noise) / res) * res
        return q_meas, qd + n[len(q) :] * s.encoder_velocity_noise


class Delay(Generic[T]):
    """A latency line: items pushed at time t come out of ``due(now)`` once now ≥ t + latency,
    in order."""

    def __init__(self, latency: float) -> None:
        self.latency = latency
        self._items: deque[tuple[float, T]] = deque()

    def push(self, t: float, item: T) -> None:
        self._items.append((t + self.latency, item))

    def due(self, now: float) -> list[T]:
        out = []
        while self._items and self._items[0][0] <= now + 1e-12:
            out.append(self._items.popleft()[1])
        return out

    def clear(self) -> None:
        self._items.clear()


def planar(x: float, y: float, yaw: float) -> np.ndarray:
    """The 4×4 transform of a platform pose (x, y, yaw) in the world's ground plane."""
    c, s = math.cos(yaw), math.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = ((c, -s), (s, c))
    T[0, 3], T[1, 3] = x, y
    return T


class Odometry:
    """The believed platform pose: each update takes the true motion since the last one in the
    platform's frame, scales it by (1 + scale error) and its turn by (1 + yaw error), adds the
    random walks (variance ∝ distance), and integrates it from the believed pose."""

    def __init__(
        self, spec: SensorSpec, rng: np.random.Generator, pose: tuple[float, float, float]
    ) -> None:
        self.spec, self.rng = spec, rng
        self.reset(pose)

    def reset(
        self,
        pose: tuple[float, float, float],
        believed: tuple[float, float, float] | None = None,
    ) -> None:
        """The platform is at ``pose`` and the odometry believes it at ``believed`` (default:
        ``pose``, e.g. at the start of an episode; another: a robot that drove there)."""
        self.true = tuple(map(float, pose))
        self.believed = self.true if believed is None else tuple(map(float, believed))
        self.distance = 0.0
        self.turned = 0.0

    def update(self, pose: tuple[float, float, float]) -> tuple[float, float, float]:
        """Take the true pose now; returns the believed one."""
        s = self.spec
        x0, y0, yaw0 = self.true
        x1, y1, yaw1 = map(float, pose)
        c, si = math.cos(yaw0), math.sin(yaw0)
        dx, dy = x1 - x0, y1 - y0
        fx, fy = c * dx + si * dy, -si * dx + c * dy  # in the platform frame at the start
        dyaw = math.atan2(math.sin(yaw1 - yaw0), math.cos(yaw1 - yaw0))
        d = math.hypot(fx, fy)
        self.true = (x1, y1, yaw1)
        if d == 0.0 and dyaw == 0.0:
            return self.believed
        self.distance += d
        self.turned += abs(dyaw)
        n = self.rng.standard_normal(3) if d > 0 else np.zeros(3)
        walk = s.odometry_walk * math.sqrt(d)
        fx = fx * (1 + s.odometry_scale_error) + n[0] * walk
        fy = fy * (1 + s.odometry_scale_error) + n[1] * walk
        dyaw_b = dyaw * (1 + s.odometry_yaw_error) + n[2] * s.odometry_yaw_walk * math.sqrt(d)
        bx, by, byaw = self.believed
        c, si = math.cos(byaw), math.sin(byaw)
        self.believed = (bx + c * fx - si * fy, by + si * fx + c * fy, byaw + dyaw_b)
        return self.believed

    def T_world_odom(self) -> np.ndarray:
        """The correction from the true world to the believed one: T_believed = T_world_odom ·
        T_true for anything fixed to the platform (its base, its cameras)."""
        return planar(*self.believed) @ np.linalg.inv(planar(*self.true))


class RobotSensors:
    """One robot's sensor models on one random stream (``seed``), starting from the true
    platform pose."""

    def __init__(self, spec: SensorSpec, seed: int, base: tuple[float, float, float]) -> None:
        rng = np.random.default_rng([seed, 15])  # apart from the depth noise's stream
        self.spec = spec
        self.imu = ImuModel(spec, rng)
        self.encoders = EncoderModel(spec, rng)
        self.odometry = Odometry(spec, rng, base)
        self.joint_states: Delay = Delay(spec.joint_latency)

    def base_velocity(self, v_x: float, v_y: float, v_yaw: float) -> tuple[float, float, float]:
        """The odometry's world velocity: the true one turned into the believed world and
        scaled like the increments."""
        s, (_, _, yaw_true), (_, _, yaw_b) = self.spec, self.odometry.true, self.odometry.believed
        c, si = math.cos(yaw_b - yaw_true), math.sin(yaw_b - yaw_true)
        k = 1 + s.odometry_scale_error
        v_yaw_b = v_yaw * (1 + s.odometry_yaw_error)
        return k * (c * v_x - si * v_y), k * (si * v_x + c * v_y), v_yaw_b
