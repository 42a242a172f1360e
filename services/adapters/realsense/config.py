"""Settings of the RealSense adapter (env AVS_REALSENSE_<FIELD> or --flag)."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from pydantic import Field, field_validator, model_validator

from schemas.keys import check_chunk
from services.common.config import ServiceSettings


class RealsenseSettings(ServiceSettings):
    """An Intel RealSense D400 camera as an AVS sensor: aligned RGB-D and IMU on the sim's keys."""

    SERVICE: ClassVar[str] = "realsense"

    camera: str = Field(
        "head_rgbd", description="camera name of the frames (perception listens to head_rgbd)"
    )
    serial: str | None = Field(None, description="serial number of the device (default: any)")
    playback: Path | None = Field(
        None,
        description="play a RealSense recording (.db3 / .bag) at its recorded rate instead of "
        "a device",
    )
    playback_wait: float = Field(
        10.0, ge=0, description="seconds a playback waits for a frame subscriber before it starts"
    )
    playback_linger: float = Field(
        1.0, ge=0, description="seconds a finished playback waits before it closes its session"
    )
    width: int = Field(640, gt=0, le=1280, description="colour (and aligned depth) width, pixels")
    height: int = Field(480, gt=0, le=800, description="colour (and aligned depth) height, pixels")
    fps: int = Field(30, gt=0, le=90, description="frames per second of depth and colour")
    depth_width: int = Field(640, gt=0, le=1280, description="depth stream width before alignment")
    depth_height: int = Field(480, gt=0, le=800, description="depth stream height before alignment")
    depth_min: float = Field(0.3, ge=0, description="nearer depths are set to 0 (no return), m")
    depth_max: float = Field(3.0, gt=0, description="farther depths are set to 0 (no return), m")
    imu: bool = Field(True, description="publish the IMU when the device has one (D435i, D455)")
    gyro_fps: int = Field(0, ge=0, description="gyro rate, Hz (0: the device's default)")
    accel_fps: int = Field(0, ge=0, description="accelerometer rate, Hz (0: the device's default)")
    imu_frame: str = Field("head_imu", description="frame name of the IMU samples")
    x: float = Field(0.0, description="camera position in the world, m (fixed: no kinematics)")
    y: float = Field(0.0, description="camera position in the world, m")
    z: float = Field(1.2, description="camera height above the floor, m")
    yaw: float = Field(0.0, description="camera heading about world z, degrees (0: along +x)")
    pitch: float = Field(30.0, ge=-90, le=90, description="camera pitch, degrees down")
    roll: float = Field(0.0, description="camera roll about its optical axis, degrees")

    @field_validator("camera")
    @classmethod
    def _camera_is_chunk(cls, v: str) -> str:
        return check_chunk(v, "camera name")

    @model_validator(mode="after")
    def _range(self) -> RealsenseSettings:
        if self.depth_max <= self.depth_min:
            raise ValueError(f"depth_max {self.depth_max} must exceed depth_min {self.depth_min}")
        return self
