"""Pure conversions from what a RealSense delivers (numpy views of its frames, its intrinsics and
extrinsics as plain numbers) to AVS's wire fields. No pyrealsense2 and no Zenoh here.

Frames: the world is z-up; the camera frame is the colour camera's optical frame (x right,
y down, z forward), which the aligned depth shares. librealsense reports the IMU of a D435i /
D455 in axes of its own (the depth module's optical axes on current firmware); its rotation to
the colour frame comes from the device's extrinsics.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from scipy.spatial.transform import Rotation

from schemas import CameraIntrinsics, RgbdFrame
from services.adapters.camera import depth_to_metres, fixed_camera_pose

#: standard gravity, m/s² (what a resting accelerometer reads, upwards)
GRAVITY = 9.80665

#: the colour formats ``to_rgb`` converts, by librealsense's name (``str(rs.format.rgb8)``)
COLOUR_FORMATS = ("rgb8", "bgr8", "rgba8", "bgra8")


class Intrinsics(Protocol):
    """What ``rs.intrinsics`` carries (any object with these attributes will do)."""

    width: int
    height: int
    fx: float
    fy: float
    ppx: float
    ppy: float
    coeffs: Sequence[float]


def camera_intrinsics(intr: Intrinsics) -> CameraIntrinsics:
    """AVS pinhole intrinsics from a librealsense stream's (``ppx, ppy`` → ``cx, cy``)."""
    return CameraIntrinsics(
        width=int(intr.width),
        height=int(intr.height),
        fx=float(intr.fx),
        fy=float(intr.fy),
        cx=float(intr.ppx),
        cy=float(intr.ppy),
    )


def distorted(intr: Intrinsics, tolerance: float = 1e-6) -> bool:
    """Whether the stream has lens distortion that a pinhole ``CameraIntrinsics`` leaves out."""
    return bool(np.any(np.abs(np.asarray(intr.coeffs, float)) > tolerance))


def depth_metres(
    z16: np.ndarray, scale: float, depth_min: float = 0.0, depth_max: float = np.inf
) -> np.ndarray:
    """Depth units (uint16, ``scale`` metres each; 0 = no return) → float32 metres, with depths
    outside ``[depth_min, depth_max]`` set to 0 (no return), as the sim does. Always a copy."""
    if z16.dtype != np.uint16 or z16.ndim != 2:
        raise ValueError(f"depth must be a 2-D uint16 image, got {z16.dtype} {z16.shape}")
    depth = depth_to_metres(z16, scale)
    depth[(depth < depth_min) | (depth > depth_max)] = 0.0
    return depth


def to_rgb(colour: np.ndarray, fmt: str) -> np.ndarray:
    """A colour image in ``fmt`` (one of ``COLOUR_FORMATS``) → a contiguous H×W×3 uint8 RGB copy."""
    fmt = fmt.rsplit(".", 1)[-1].lower()  # str(rs.format.rgb8) is "format.rgb8"
    channels = {"rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}.get(fmt)
    if channels is None:
        raise ValueError(f"colour format {fmt!r} is not one of {', '.join(COLOUR_FORMATS)}")
    if colour.dtype != np.uint8 or colour.ndim != 3 or colour.shape[2] != channels:
        got = f"{colour.dtype} {colour.shape}"
        raise ValueError(f"{fmt} image must be H×W×{channels} uint8, got {got}")
    rgb = colour[..., :3] if fmt.startswith("rgb") else colour[..., 2::-1]
    return np.array(rgb, dtype=np.uint8, order="C", copy=True)


def T_world_camera(
    x: float, y: float, z: float, yaw_deg: float, pitch_deg: float, roll_deg: float = 0.0
) -> np.ndarray:
    """The fixed pose of an optical camera frame in the z-up world: at (x, y, z), heading
    ``yaw`` about world z (0: looking along +x), pitched ``pitch`` degrees down, rolled
    ``roll`` about its optical axis. With no kinematics this stands in for the robot's."""
    radians = np.radians([roll_deg, pitch_deg, yaw_deg])
    return fixed_camera_pose(x, y, z, *radians)


def extrinsics_matrix(rotation: Sequence[float], translation: Sequence[float]) -> np.ndarray:
    """``rs.extrinsics`` of ``a.get_extrinsics_to(b)`` (rotation column-major, as librealsense
    stores it) → the 4×4 ``T_b_a`` that maps points of frame a into frame b."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(rotation, float).reshape(3, 3).T
    T[:3, 3] = np.asarray(translation, float)
    return T


def quaternion(R: np.ndarray) -> np.ndarray:
    """A rotation matrix as a unit quaternion (w, x, y, z), w ≥ 0."""
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    q = np.array([w, x, y, z])
    return -q if w < 0 else q


def gravity_tilt(accel: np.ndarray) -> tuple[float, float]:
    """(pitch down, roll) in degrees of an optical frame whose resting accelerometer reads
    ``accel`` (specific force, in that frame's axes): the inverse of ``T_world_camera``'s
    pitch and roll, to check a configured pose against the IMU."""
    ax, ay, az = np.asarray(accel, float)
    pitch = np.degrees(np.arctan2(-az, np.hypot(ax, ay)))
    roll = np.degrees(np.arctan2(-ax, -ay))
    return float(pitch), float(roll)


def rgbd_frame(
    *,
    seq: int,
    stamp: float,
    camera: str,
    intrinsics: CameraIntrinsics,
    rgb: np.ndarray,
    depth: np.ndarray,
    T_world_camera: np.ndarray,
    depth_min: float,
    depth_max: float,
) -> RgbdFrame:
    """The wire frame of one aligned depth + colour pair (both in the colour camera's pixels)."""
    return RgbdFrame(
        seq=seq,
        stamp=stamp,
        camera=camera,
        intrinsics=intrinsics,
        rgb=rgb,
        depth=depth,
        T_world_camera=T_world_camera,
        depth_min=depth_min,
        depth_max=depth_max,
    )


@dataclass
class ImuSampleFields:
    """The fields of one ImuSample (without seq and the frame name)."""

    stamp: float
    angular_velocity: np.ndarray
    linear_acceleration: np.ndarray


class ImuPairing:
    """Gyro and accelerometer come as separate streams at different rates (D435i: gyro 200 or
    400 Hz, accel 63 or 250 Hz). One sample per gyro reading, carrying the newest accel
    reading (realsense-ros's ``unite_imu_method: copy``); gyro readings before the first accel
    one are dropped."""

    def __init__(self) -> None:
        self._accel: np.ndarray | None = None

    def accel(self, xyz: Sequence[float]) -> None:
        self._accel = np.array(xyz, dtype=float)

    def gyro(self, stamp: float, xyz: Sequence[float]) -> ImuSampleFields | None:
        if self._accel is None:
            return None
        return ImuSampleFields(stamp, np.array(xyz, dtype=float), self._accel.copy())
