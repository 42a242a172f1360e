"""What every camera adapter needs, whatever delivers the images (a bag, a RealSense): depth
to metres, and the optical frame's pose from a camera body's. Pure numpy."""

from __future__ import annotations

import math

import numpy as np

#: The optical frame (x right, y down, z forward: RgbdFrame's and ROS's ``*_optical_frame``)
#: in a camera body frame (REP 103: x forward, y left, z up). Columns: the optical axes.
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def depth_to_metres(depth: np.ndarray, scale: float | None = None) -> np.ndarray:
    """Depth as float32 metres, 0 where there is no return (0, NaN, ±inf, negative).

    Integer depth (16UC1, a RealSense z16 image) is in units of ``scale`` metres (default
    0.001: millimetres); float depth (32FC1) is in metres unless ``scale`` says otherwise.
    """
    depth = np.asarray(depth)
    if depth.dtype.kind in "ui":
        unit = np.float32(0.001 if scale is None else scale)
        return depth.astype(np.float32) * unit
    if depth.dtype.kind != "f":
        raise ValueError(f"depth of dtype {depth.dtype} is neither integer nor float")
    metres = depth.astype(np.float32, copy=True)
    if scale is not None and scale != 1.0:
        metres *= np.float32(scale)
    metres[~(np.isfinite(metres) & (metres > 0))] = 0.0
    return metres


def optical_pose_from_body(T_world_body: np.ndarray) -> np.ndarray:
    """T_world_camera of the optical frame (x right, y down, z forward) from the pose of a
    camera body frame (x forward, y left, z up) at the same origin."""
    T = np.array(T_world_body, float, copy=True)
    T[:3, :3] = T[:3, :3] @ R_BODY_OPTICAL
    return T


def fixed_camera_pose(
    x: float, y: float, z: float, roll: float, pitch: float, yaw: float
) -> np.ndarray:
    """T_world_camera (optical) of a camera whose body frame (x forward, y left, z up) sits at
    (x, y, z) m with roll, pitch, yaw in radians (R = Rz(yaw)·Ry(pitch)·Rx(roll); pitch > 0
    looks down)."""
    cr, sr, cp, sp, cy, sy = (
        math.cos(roll),
        math.sin(roll),
        math.cos(pitch),
        math.sin(pitch),
        math.cos(yaw),
        math.sin(yaw),
    )
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    Rx = np.array([[1.0, 0, 0], [0, cr, -sr], [0, sr, cr]])
    T = np.eye(4)
    T[:3, :3] = Rz @ Ry @ Rx
    T[:3, 3] = (x, y, z)
    return optical_pose_from_body(T)
