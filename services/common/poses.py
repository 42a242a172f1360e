"""Comparing rigid poses (4×4 homogeneous transforms)."""

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
