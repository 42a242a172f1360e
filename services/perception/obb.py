"""Oriented bounding boxes: from points and primitive models, and their ε-extended
intersection (thesis Eq. 3.5/3.6) by the separating axis theorem."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError


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
    e1 = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _min_area_rectangle(Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, unit direction of the first side, side lengths) of the smallest rectangle
    around 2D points (rotating calipers over the convex hull's edges)."""
    try:
        H = Q[ConvexHull(Q).vertices]
    except (QhullError, ValueError):
        H = Q
    if len(H) < 2:
        return Q.mean(0) if len(Q) else np.zeros(2), np.array([1.0, 0]), np.zeros(2)
    edges = np.roll(H, -1, axis=0) - H
    angles = np.unique(np.mod(np.arctan2(edges[:, 1], edges[:, 0]), np.pi / 2))
    c, s = np.cos(angles), np.sin(angles)
    u = H[:, 0:1] * c + H[:, 1:2] * s  # (hull, angles)
    v = -H[:, 0:1] * s + H[:, 1:2] * c
    area = np.ptp(u, 0) * np.ptp(v, 0)
    k = int(np.argmin(area))
    d1 = np.array([c[k], s[k]])
    d2 = np.array([-s[k], c[k]])
    mid = (u[:, k].max() + u[:, k].min()) / 2 * d1 + (v[:, k].max() + v[:, k].min()) / 2 * d2
    return mid, d1, np.array([np.ptp(u[:, k]), np.ptp(v[:, k])])


def plane_box(points: np.ndarray, normal: np.ndarray) -> Box:
    """Normal as the third axis, the smallest in-plane rectangle for the other two (its
    orientation from the hull of at most 2,000 of the points, its sides from all of them)."""
    e1, e2 = _frame(normal)
    o = points.mean(0)
    Q = np.column_stack([(points - o) @ e1, (points - o) @ e2])
    sample = Q if len(Q) <= 2000 else Q[np.linspace(0, len(Q) - 1, 2000).astype(int)]
    _, d1, _ = _min_area_rectangle(sample)
    d2 = np.array([-d1[1], d1[0]])
    u, v = Q @ d1, Q @ d2
    mid = (u.max() + u.min()) / 2 * d1 + (v.max() + v.min()) / 2 * d2
    a1 = d1[0] * e1 + d1[1] * e2
    a2 = np.cross(normal, a1)
    h = (points - o) @ normal
    center = o + mid[0] * e1 + mid[1] * e2 + (h.max() + h.min()) / 2 * normal
    return Box(
        center, np.column_stack([a1, a2, normal]), np.array([np.ptp(u), np.ptp(v), np.ptp(h)])
    )


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
    A, B = a.rotation, b.rotation
    axes = np.concatenate([A.T, B.T, np.cross(A.T[:, None, :], B.T[None, :, :]).reshape(9, 3)])
    norms = np.linalg.norm(axes, axis=1)
    axes = axes[norms > 1e-9] / norms[norms > 1e-9, None]
    ra = np.abs(axes @ A) @ (a.extent / 2 + epsilon)
    rb = np.abs(axes @ B) @ (b.extent / 2 + epsilon)
    return bool(np.all(np.abs(axes @ (b.center - a.center)) <= ra + rb))
