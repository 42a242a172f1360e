"""Oriented bounding boxes: from points and primitive models, and their ε-extended
intersection (thesis Eq. 3.5/3.6) by the separating axis theorem."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from services.common.sat import boxes_overlap
from services.perception import kernels


def cross(a, b) -> np.ndarray:
    """a × b of two 3-vectors (np.cross costs ten times as much on one pair; perception calls
    it a hundred times a frame)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


@dataclass
class Box:
    center: np.ndarray  # (3,)
    rotation: np.ndarray  # (3, 3), columns are the box axes
    extent: np.ndarray  # (3,) full side lengths

    def corners(self) -> np.ndarray:
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        return self.center + (signs * self.extent / 2) @ self.rotation.T

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        local = (points - self.center) @ self.rotation
        return np.all(np.abs(local) <= self.extent / 2 + margin, axis=1)

    @property
    def z_min(self) -> float:
        return float(self.center[2] - np.abs(self.rotation[2]) @ self.extent / 2)

    @property
    def z_max(self) -> float:
        return float(self.center[2] + np.abs(self.rotation[2]) @ self.extent / 2)


def _frame(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = cross(axis, (1.0, 0.0, 0.0) if abs(axis[0]) < 0.9 else (0.0, 1.0, 0.0))
    e1 /= math.sqrt(e1 @ e1)
    return e1, cross(axis, e1)


def _rectangle_direction(Q: np.ndarray) -> np.ndarray:
    """The unit direction of the first side of the smallest rectangle around 2D points, at an
    angle in [0°, 90°) (OpenCV's rotating calipers over the convex hull, ten times faster than
    qhull and calipers in numpy: the same rectangle on 2,000 random point sets)."""
    if len(Q) < 2:
        return np.array([1.0, 0.0])
    _, _, angle = cv2.minAreaRect(np.ascontiguousarray(Q, np.float32))
    phi = math.radians(angle) % (math.pi / 2)
    return np.array([math.cos(phi), math.sin(phi)])


def plane_box(points: np.ndarray, normal: np.ndarray) -> Box:
    """Normal as the third axis, the smallest in-plane rectangle for the other two (its
    orientation from the hull of at most 2,000 of the points, its sides from all of them).
    The points' frame coordinates and spans compiled: half of a frame's box time was a dozen
    numpy passes over a table's tens of thousands of points."""
    e1, e2 = _frame(normal)
    normal = np.asarray(normal, np.float64)
    o, Q, h_lo, h_hi = kernels.plane_coords(np.ascontiguousarray(points, np.float64), e1, e2,
                                            normal)  # fmt: skip
    sample = Q if len(Q) <= 2000 else Q[np.linspace(0, len(Q) - 1, 2000).astype(int)]
    d1 = _rectangle_direction(sample)
    u0, u1, v0, v1 = kernels.rectangle_span(Q, d1)
    d2 = np.array([-d1[1], d1[0]])
    mid = (u1 + u0) / 2 * d1 + (v1 + v0) / 2 * d2
    a1 = d1[0] * e1 + d1[1] * e2
    a2 = cross(normal, a1)
    center = o + mid[0] * e1 + mid[1] * e2 + (h_hi + h_lo) / 2 * normal
    return Box(center, np.column_stack([a1, a2, normal]), np.array([u1 - u0, v1 - v0, h_hi - h_lo]))


def axis_box(points: np.ndarray, axis: np.ndarray, center: np.ndarray, radius: float) -> Box:
    """A cylinder's box: 2r across, the points' span along the axis."""
    e1, e2 = _frame(axis)
    t = (points - center) @ axis
    mid = center + (t.max() + t.min()) / 2 * axis
    return Box(mid, np.column_stack([e1, e2, axis]), np.array([2 * radius, 2 * radius, np.ptp(t)]))


def frame_box(points: np.ndarray, rotation: np.ndarray, trim: float = 0.0) -> Box:
    """The box of the points in a given frame; ``trim`` (percent) ignores that share of the
    points at each end of every axis, so depth noise does not inflate the box."""
    local = points @ rotation
    if trim > 0:
        lo, hi = np.percentile(local, [trim, 100 - trim], axis=0)
    else:
        lo, hi = local.min(0), local.max(0)
    return Box(rotation @ ((lo + hi) / 2), rotation, hi - lo)


def pca_box(points: np.ndarray) -> Box:
    c = points.mean(0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    R = vt.T
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1
    return frame_box(points, R)


def intersect(a: Box, b: Box, epsilon: float = 0.0) -> bool:
    """Do the boxes, each extended by ``epsilon`` on every side, overlap (SAT, 15 axes)?"""
    return boxes_overlap(a.rotation, a.center, a.extent, b.rotation, b.center, b.extent, epsilon)
