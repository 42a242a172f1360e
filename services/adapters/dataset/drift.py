"""An odometry-like drift given to a recording's poses (``avs replay-dataset --drift MM,DEG``),
so that view registration (thesis A.5) has something to correct on real frames whose reference
poses are right.

Definition, in the published world (z up, after ``T_up``): the ``k``-th played frame's pose
(k = 0, 1, …; its ``seq``) is moved by

    D_k = Trans(k · mm · x̂) · Rot_z(k · deg about the vertical through ``pivot``)

``T_published = D_k · T_world_camera``: the whole world as the odometry sees it is turned by
k·deg of yaw about the vertical through ``pivot`` (the first played camera's position: where
the odometry started) and shifted k·mm along world +x. It is one rigid transform per frame that
grows with k, as an odometry frame drifts from the map (the scene memory's model: T_world =
T_world_odom · T_odometry, so the correction that undoes it is ``D_k⁻¹``). The camera's
position error grows with the distance driven (k·mm) and with its distance from the pivot
(yaw), its heading error is k·deg. Frame 0 is not moved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Drift:
    """Per frame: ``mm`` millimetres along world +x and ``deg`` degrees of yaw (about +z)."""

    mm: float
    deg: float

    @classmethod
    def parse(cls, text: str) -> Drift:
        """``"MM,DEG"`` (ValueError otherwise)."""
        try:
            mm, deg = (float(v) for v in text.split(","))
        except ValueError:
            raise ValueError(f"--drift wants MM,DEG (per frame), not {text!r}") from None
        if not (math.isfinite(mm) and math.isfinite(deg)):
            raise ValueError(f"--drift wants finite numbers, not {text!r}")
        return cls(mm, deg)


def drift_transform(k: int, drift: Drift, pivot: np.ndarray) -> np.ndarray:
    """D_k (4×4, world → drifted world): k·deg of yaw about the vertical through ``pivot``
    (3,), then k·mm along +x."""
    a = math.radians(k * drift.deg)
    c, s = math.cos(a), math.sin(a)
    D = np.eye(4)
    D[:2, :2] = [[c, -s], [s, c]]
    p = np.asarray(pivot, float)
    D[:3, 3] = p - D[:3, :3] @ p
    D[0, 3] += k * drift.mm * 1e-3
    return D


def drifted(T_world_camera: np.ndarray, k: int, drift: Drift, pivot: np.ndarray) -> np.ndarray:
    """The ``k``-th frame's pose as the drifting odometry gives it: D_k · T_world_camera."""
    return drift_transform(k, drift, pivot) @ np.asarray(T_world_camera, float)
