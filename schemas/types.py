"""Reusable annotated field types: poses, vectors, quaternions.

Frames follow the names: ``T_world_camera`` maps points from the camera frame to the world
frame (4×4 homogeneous, float64). The world is z-up; camera frames are optical (OpenCV: x right,
y down, z forward). Quaternions are (w, x, y, z), as in MuJoCo.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import GetCoreSchemaHandler
from pydantic_core import core_schema

from schemas.arrays import Array


class _Check:
    """An annotation that checks a validated array further; also a marker for test strategies."""

    def check(self, a: np.ndarray) -> None:
        raise NotImplementedError

    def _run(self, a: np.ndarray) -> np.ndarray:
        self.check(a)
        return a

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler):
        return core_schema.no_info_after_validator_function(self._run, handler(source))


#: arrays up to this size are checked entry by entry in Python: a 1 kHz message's 3-vectors
#: cost a fifth of what numpy's per-call overhead would
SMALL = 16


def _finite(a: np.ndarray) -> bool:
    if a.size <= SMALL:
        return all(map(math.isfinite, a.ravel().tolist()))
    return bool(np.isfinite(a).all())


def _unit(a: np.ndarray) -> bool:
    """Finite with unit norm (within 1e-4)."""
    if not _finite(a):
        return False
    v = a.ravel().tolist() if a.size <= SMALL else None
    norm = math.sqrt(math.fsum(x * x for x in v)) if v is not None else float(np.linalg.norm(a))
    return abs(norm - 1.0) <= 1e-4


class Finite(_Check):
    """Every entry is finite."""

    def check(self, a: np.ndarray) -> None:
        if not _finite(a):
            raise ValueError("entries must be finite")


class Rigid(_Check):
    """A rigid transform (or a stack of them): last row [0 0 0 1], rotation orthonormal, det +1."""

    def check(self, a: np.ndarray) -> None:
        T = a.reshape(-1, 4, 4)
        if not np.isfinite(T).all():
            raise ValueError("pose has non-finite entries")
        if T.size and np.abs(T[:, 3] - _LAST_ROW).max() > 1e-9:
            raise ValueError("a pose's last row must be [0, 0, 0, 1]")
        R = T[:, :3, :3]
        if T.size and np.abs(R.transpose(0, 2, 1) @ R - _EYE3).max() > 1e-5:
            raise ValueError("a pose's rotation is not orthonormal")
        # orthonormal, so det is ±1: the sign of (r0 × r1)·r2 tells which
        r0, r1, r2 = R[:, :, 0], R[:, :, 1], R[:, :, 2]
        det = (
            r2[:, 0] * (r0[:, 1] * r1[:, 2] - r0[:, 2] * r1[:, 1])
            + r2[:, 1] * (r0[:, 2] * r1[:, 0] - r0[:, 0] * r1[:, 2])
            + r2[:, 2] * (r0[:, 0] * r1[:, 1] - r0[:, 1] * r1[:, 0])
        )
        if (det < 0).any():
            raise ValueError("a pose's rotation is a reflection (det -1)")


_LAST_ROW = np.array([0.0, 0.0, 0.0, 1.0])
_EYE3 = np.eye(3)


class UnitQuaternion(_Check):
    """A unit quaternion (w, x, y, z)."""

    def check(self, a: np.ndarray) -> None:
        if not _unit(a):
            raise ValueError("quaternion must be finite with unit norm")


class UnitVector(_Check):
    """A unit 3-vector (a direction or a normal)."""

    def check(self, a: np.ndarray) -> None:
        if not _unit(a):
            raise ValueError("direction must be finite with unit norm")


#: A rigid transform in SE(3), 4×4 float64.
Pose = Annotated[np.ndarray, Array("float64", (4, 4)), Rigid()]

#: A stack of rigid transforms, k×4×4 float64.
Poses = Annotated[np.ndarray, Array("float64", (None, 4, 4)), Rigid()]

#: A finite 3-vector, float64.
Vec3 = Annotated[np.ndarray, Array("float64", (3,)), Finite()]

#: A unit 3-vector, float64.
Direction = Annotated[np.ndarray, Array("float64", (3,)), UnitVector()]

#: A unit quaternion (w, x, y, z), float64.
Quat = Annotated[np.ndarray, Array("float64", (4,)), UnitQuaternion()]


def check_roi(low: np.ndarray | None, high: np.ndarray | None) -> None:
    """An optional roi comes whole (both corners or neither), its low corner below its high
    one on every axis; ValueError otherwise (a model validator's message)."""
    if (low is None) != (high is None):
        raise ValueError("roi_min and roi_max come together")
    if low is not None and not (np.asarray(low) < np.asarray(high)).all():
        raise ValueError("roi_min must be below roi_max on every axis")
