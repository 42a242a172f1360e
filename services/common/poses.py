"""Comparing and correcting rigid poses (4×4 homogeneous transforms)."""

from __future__ import annotations

import math

import numpy as np


def pose_difference(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    """How far apart two poses are: the distance of their origins (m) and the angle of the
    rotation between them (degrees)."""
    cos = (np.trace(A[:3, :3].T @ B[:3, :3]) - 1) / 2
    return (
        float(np.linalg.norm(A[:3, 3] - B[:3, 3])),
        math.degrees(math.acos(max(-1.0, min(1.0, float(cos))))),
    )


def corrected_base(
    T_world_odom: np.ndarray | None,
    pose: tuple[float, float, float],
    twist: tuple[float, float, float],
) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """The platform's odometry pose (x, y, yaw) and world velocity (vx, vy, yaw rate) in the
    registered world: T_world = T_world_odom · T_odom (memory/pose_correction, thesis A.5).
    Only the correction's planar part is used (x, y and the rotation about z)."""
    if T_world_odom is None:
        return pose, twist
    T = np.asarray(T_world_odom, float)
    c, s = float(T[0, 0]), float(T[1, 0])
    n = math.hypot(c, s) or 1.0
    c, s = c / n, s / n
    x, y, yaw = pose
    vx, vy, w = twist
    return (
        (c * x - s * y + float(T[0, 3]), s * x + c * y + float(T[1, 3]), yaw + math.atan2(s, c)),
        (c * vx - s * vy, s * vx + c * vy, w),
    )
