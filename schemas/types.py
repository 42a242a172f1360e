"""Reusable annotated field types: poses, vectors, quaternions.

Frames follow the names: ``T_world_camera`` maps points from the camera frame to the world
frame (4×4 homogeneous, float64). The world is z-up; camera frames are optical (OpenCV: x right,
y down, z forward). Quaternions are (w, x, y, z), as in MuJoCo.
"""

from __future__ import annotations

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


class Finite(_Check):
    """Every entry is finite."""

    def check(self, a: np.ndarray) -> None:
        if not np.all(np.isfinite(a)):
            raise ValueError("entries must be finite")


class Rigid(_Check):
    """A rigid transform (or a stack of them): last row [0 0 0 1], rotation orthonormal, det +1."""

    def check(self, a: np.ndarray) -> None:
        if not np.all(np.isfinite(a)):
            raise ValueError("pose has non-finite entries")
        T = a.reshape(-1, 4, 4)
        if not np.allclose(T[:, 3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
            raise ValueError("a pose's last row must be [0, 0, 0, 1]")
        R = T[:, :3, :3]
        RtR = np.einsum("kji,kjl->kil", R, R)
        if not np.allclose(RtR, np.eye(3), atol=1e-5) or np.any(np.linalg.det(R) < 0):
            raise ValueError("a pose's rotation is not orthonormal with det +1")


class UnitQuaternion(_Check):
    """A unit quaternion (w, x, y, z)."""

    def check(self, a: np.ndarray) -> None:
        if not np.all(np.isfinite(a)) or abs(float(np.linalg.norm(a)) - 1.0) > 1e-4:
            raise ValueError("quaternion must be finite with unit norm")


class UnitVector(_Check):
    """A unit 3-vector (a direction or a normal)."""

    def check(self, a: np.ndarray) -> None:
        if not np.all(np.isfinite(a)) or abs(float(np.linalg.norm(a)) - 1.0) > 1e-4:
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
