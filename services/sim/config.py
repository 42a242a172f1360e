"""Settings of the sim service (env AVS_SIM_<FIELD> or --flag)."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from pydantic import Field

from services.common.config import ServiceSettings


class SimSettings(ServiceSettings):
    """MuJoCo simulation of ARMAR-6 / ARMAR-III: RGB-D, IMU, joints, odometry, ground truth."""

    SERVICE: ClassVar[str] = "sim"

    scene: str = Field("tabletop_occluded", description="built-in scene name or an MJCF file")
    lockstep: bool = Field(
        False,
        description="advance only when sim/control asks (step, render) instead of "
        "running on the wall clock",
    )
    replay: Path | None = Field(
        None, description="play an MCAP recording (avs record) instead, with its timing"
    )
    replay_wait: float = Field(
        10.0, ge=0, description="seconds a replay waits for a subscriber before it starts"
    )
    replay_linger: float = Field(
        1.0, ge=0, description="seconds a finished replay waits before it closes its session"
    )
    speed: float = Field(1.0, gt=0, description="realtime factor (realtime mode and replay)")
    cameras: list[str] = Field(
        default_factory=list, description="cameras to publish (default: the robot's main one)"
    )
    width: int = Field(640, gt=0, le=1280, description="image width, pixels")
    height: int = Field(480, gt=0, le=960, description="image height, pixels")
    fps: float = Field(15.0, ge=0, description="frames per second per camera (realtime mode)")
    imu_rate: float = Field(1000.0, gt=0, description="IMU samples per second (sim time)")
    state_rate: float = Field(200.0, gt=0, description="joint state and odometry per second")
    timestep: float = Field(0.001, gt=0, le=0.01, description="physics step, s")
    sleep: bool = Field(
        True, description="objects at rest sleep (MuJoCo islands): a step 12 µs, not 44 (kitchen)"
    )
    noise: bool = Field(True, description="structured-light depth noise")
    shadows: bool = Field(False, description="render shadows (about 4x slower on Mesa)")
    seed: int = Field(0, description="seed of the depth noise and the sensor models")
    sensors: bool = Field(
        False,
        description="sensor models (services/sim/sensors.py): gyro noise and bias, encoder "
        "quantisation and noise, joint-state and frame latency, odometry drift; off: the "
        "simulator's truth",
    )
    realtime: bool = Field(
        True,
        description="real-time scheduling of physics, IMU and Zenoh's threads (SCHED_RR, else "
        "nice -10) where permitted; the renderer stays ordinary",
    )
