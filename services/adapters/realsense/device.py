"""pyrealsense2, imported only here and only when asked: which streams to ask a device (or a
recording) for, and the facts of the started streams that the conversions need."""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from schemas import CameraIntrinsics
from services.adapters.realsense import core
from services.adapters.realsense.config import RealsenseSettings

INSTALL_HINT = "pip install 'avs[realsense]'"


class RealsenseError(RuntimeError):
    """pyrealsense2 is not installed, or no device (or recording) can give the streams."""


def import_rs() -> ModuleType:
    """The pyrealsense2 module, or a ``RealsenseError`` that says how to install it."""
    try:
        import pyrealsense2 as rs
    except ImportError as e:
        raise RealsenseError(
            f"the RealSense adapter needs pyrealsense2 ({e}): {INSTALL_HINT}"
        ) from e
    return rs


def stream_config(rs: ModuleType, settings: RealsenseSettings, imu: bool) -> Any:
    """An ``rs.config`` for depth (z16) and colour (rgb8) at the set sizes and rate, and with
    ``imu`` gyro and accelerometer; from ``settings.playback`` or the device ``serial``."""
    config = rs.config()
    if settings.playback is not None:
        if not settings.playback.is_file():
            raise RealsenseError(f"no recording at {settings.playback}")
        config.enable_device_from_file(str(settings.playback), repeat_playback=False)
    elif settings.serial:
        config.enable_device(settings.serial)
    s = settings
    config.enable_stream(rs.stream.depth, s.depth_width, s.depth_height, rs.format.z16, s.fps)
    config.enable_stream(rs.stream.color, s.width, s.height, rs.format.rgb8, s.fps)
    if imu:
        config.enable_stream(rs.stream.accel, rs.format.motion_xyz32f, s.accel_fps)
        config.enable_stream(rs.stream.gyro, rs.format.motion_xyz32f, s.gyro_fps)
    return config


def resolvable_config(
    rs: ModuleType, pipeline: Any, settings: RealsenseSettings
) -> tuple[Any, bool]:
    """The config to start ``pipeline`` with and whether it includes the IMU: with it when
    asked for and the device (or recording) has one, else without. Raises
    ``RealsenseError`` when not even depth and colour resolve."""
    wrapper = rs.pipeline_wrapper(pipeline)
    if settings.imu:
        config = stream_config(rs, settings, imu=True)
        if config.can_resolve(wrapper):
            return config, True
    config = stream_config(rs, settings, imu=False)
    if not config.can_resolve(wrapper):
        where = settings.playback or (f"device {settings.serial}" if settings.serial else None)
        raise RealsenseError(
            f"no RealSense {where or 'device'} gives depth {settings.depth_width}×"
            f"{settings.depth_height} and colour {settings.width}×{settings.height} (rgb8) at "
            f"{settings.fps} Hz (is a camera connected, over USB 3?)"
        )
    return config, False


@dataclass(frozen=True)
class StreamFacts:
    """What the conversions need from a started pipeline."""

    device: str
    serial: str
    depth_scale: float
    intrinsics: CameraIntrinsics
    distorted: bool
    colour_format: str
    R_colour_imu: np.ndarray | None  # None: no IMU, or no extrinsics to place it


def stream_facts(rs: ModuleType, profile: Any, imu: bool) -> StreamFacts:
    """Facts of a started ``rs.pipeline_profile``: the device's depth scale, the colour
    stream's intrinsics (which the aligned depth shares), and the IMU's rotation into it."""
    device = profile.get_device()
    colour = profile.get_stream(rs.stream.color).as_video_stream_profile()
    intr = colour.get_intrinsics()
    R = None
    if imu:
        # the IMU's own extrinsics when the device (or recording) has them; else the depth
        # imager's, whose axes librealsense reports a D435i's / D455's IMU readings in
        for source in (rs.stream.accel, rs.stream.depth):
            try:
                ext = profile.get_stream(source).get_extrinsics_to(colour)
            except RuntimeError:
                continue
            R = core.extrinsics_matrix(ext.rotation, ext.translation)[:3, :3]
            break

    def info(what: Any) -> str:
        return device.get_info(what) if device.supports(what) else "?"

    return StreamFacts(
        device=info(rs.camera_info.name),
        serial=info(rs.camera_info.serial_number),
        depth_scale=float(device.first_depth_sensor().get_depth_scale()),
        intrinsics=core.camera_intrinsics(intr),
        distorted=core.distorted(intr),
        colour_format=str(colour.format()),
        R_colour_imu=R,
    )
