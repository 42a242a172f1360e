"""RANSAC for planes, cylinders and spheres (Algorithm 1's fitting step), vectorised.

Hypotheses come from minimal samples that use the normals, as in Schnabel et al. (2007): a
plane from three points, a cylinder from two oriented points (axis n1 × n2), a sphere from two
oriented points (where their normal lines meet). All hypotheses are scored at once on a subset
of the segment (distance below ``dist`` and normal within ``angle_deg``; ``subset``: SUBSET
points drawn at random, or None: every point), the best one is refined by least squares on its
inliers, and the inliers are counted on the whole segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from services.perception import kernels
from services.perception.obb import cross

SUBSET = 500  # points scoring the hypotheses (the fits' ``subset``)
SIN_MIN = float(np.sin(np.radians(5)))  # cylinder pairs' normals at least 5° apart


@dataclass
class Fit:
    kind: str  # plane | cylinder | sphere
    inliers: np.ndarray  # bool mask over the segment's points
    normal: np.ndarray = field(default_factory=lambda: np.zeros(3))  # plane
    d: float = 0.0  # plane: n·x + d = 0
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))  # cylinder / sphere
    axis: np.ndarray = field(default_factory=lambda: np.zeros(3))  # cylinder
    radius: float = 0.0

    @property
    def count(self) -> int:
        return int(np.count_nonzero(self.inliers))


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 1e-12)


# -- residuals ---------------------------------------------------------------------------------


def plane_residuals(X, N, normal, d):
    return np.abs(X @ normal + d), np.abs(N @ normal)


def cylinder_residuals(X, N, center, axis, radius):
    v = X - center
    radial = v - np.outer(v @ axis, axis)
    r = np.linalg.norm(radial, axis=1)
    cos = np.abs(np.einsum("ij,ij->i", N, radial)) / np.maximum(r, 1e-9)
    return np.abs(r - radius), cos


def sphere_residuals(X, N, center, radius):
    v = X - center
    r = np.linalg.norm(v, axis=1)
    cos = np.abs(np.einsum("ij,ij->i", N, v)) / np.maximum(r, 1e-9)
    return np.abs(r - radius), cos


# -- least-squares refinement ------------------------------------------------------------------


def refine_plane(X: np.ndarray) -> tuple[np.ndarray, float]:
    c = X.mean(axis=0)
    _, _, vt = np.linalg.svd(X - c, full_matrices=False)
    n = vt[2]
    return n, float(-n @ c)


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares by the normal equations (small, well-posed systems; much faster than
    lstsq's SVD)."""
    AtA = A.T @ A
    try:
        return np.linalg.solve(AtA, A.T @ b)
    except np.linalg.LinAlgError:
        return np.linalg.lstsq(A, b, rcond=None)[0]


def _circle_fit(Q: np.ndarray, iterations: int = 4) -> tuple[np.ndarray, float]:
    """Circle fit in 2D: algebraic (Kåsa) start, then Gauss-Newton on the geometric distance
    (Kåsa alone shrinks the radius of a short, noisy arc). Compiled; numpy (least squares by
    SVD) only where a system is singular."""
    cx, cy, r, ok = kernels.circle_fit(np.ascontiguousarray(Q, np.float64), iterations)
    if ok:
        return np.array([cx, cy]), r
    return _circle_fit_numpy(Q, iterations)


def _circle_fit_numpy(Q: np.ndarray, iterations: int = 4) -> tuple[np.ndarray, float]:
    A = np.column_stack([2 * Q, np.ones(len(Q))])
    sol = _solve(A, (Q**2).sum(1))
    c = sol[:2]
    r = float(np.sqrt(max(sol[2] + c @ c, 0.0)))
    for _ in range(iterations):
        d = Q - c
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        J = np.column_stack([-d / dist[:, None], -np.ones(len(Q))])
        step = _solve(J, r - dist)
        c, r = c + step[:2], r + float(step[2])
        if abs(step).max() < 1e-6:
            break
    return c, abs(r)


def refine_cylinder(
    X: np.ndarray, N: np.ndarray, axis: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float]:
    """Axis = direction least aligned with the normals; centre and radius from a circle fit of
    the points projected along it."""
    w, v = np.linalg.eigh(N.T @ N)
    # the normals pin the axis down only when they sweep an arc (two clearly non-zero
    # eigenvalues); on a nearly flat patch keep the hypothesis' axis
    a = v[:, 0] if w[1] > 4 * max(w[0], 1e-12) else axis
    a = a / np.linalg.norm(a)
    e1 = _unit(cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0]))
    e2 = cross(a, e1)
    o = X.mean(axis=0)
    Q = np.column_stack([(X - o) @ e1, (X - o) @ e2])
    c2, r = _circle_fit(Q)
    return o + c2[0] * e1 + c2[1] * e2, a, r


def refine_sphere(X: np.ndarray) -> tuple[np.ndarray, float]:
    A = np.column_stack([2 * X, np.ones(len(X))])
    sol = _solve(A, (X**2).sum(1))
    c = sol[:3]
    return c, float(np.sqrt(max(sol[3] + c @ c, 0.0)))


# -- hypotheses --------------------------------------------------------------------------------


def _pairs(rng: np.random.Generator, n: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    i = rng.integers(0, n, k)
    j = rng.integers(0, n, k)
    keep = i != j
    return i[keep], j[keep]


def _subset(rng: np.random.Generator, n: int, size: int | None) -> np.ndarray:
    """The indices of the points that score the hypotheses: ``size`` drawn at random (with
    replacement) of ``n``, or all of them when ``n`` ≤ ``size`` or ``size`` is None."""
    return np.arange(n) if size is None or n <= size else rng.integers(0, n, size)


def fit_plane(X, N, rng, dist, cos_min, hypotheses=48, subset=SUBSET) -> Fit | None:
    n = len(X)
    if n < 3:
        return None
    triples = rng.integers(0, n, (hypotheses, 3))
    normal, d, mask, found = kernels.plane_ransac(
        X, N, triples, _subset(rng, n, subset), dist, cos_min, 2
    )
    if not found:
        return None
    return Fit("plane", mask, normal=normal, d=float(d))


def fit_cylinder(
    X, N, rng, dist, cos_min, r_min, r_max, hypotheses=32, subset=SUBSET
) -> Fit | None:
    n = len(X)
    if n < 10:
        return None
    i, j = _pairs(rng, n, hypotheses)
    # axis n1 × n2, centre where the normal lines meet across it (compiled: 32 hypotheses in
    # numpy were some 20 array operations of per-call overhead)
    centers, axes, radii = kernels.cylinder_hypotheses(X, N, i, j, SIN_MIN, r_min, r_max)
    if len(radii) == 0:
        return None
    score = kernels.score_cylinders(
        X, N, _subset(rng, n, subset), centers, axes, radii, dist, cos_min
    )
    best = int(np.argmax(score))
    center, axis, radius = centers[best], axes[best], float(radii[best])
    for _ in range(2):
        mask = kernels.cylinder_inliers(X, N, center, axis, radius, dist, cos_min)
        if mask.sum() < 10:
            return None
        center, refined, radius, ok = kernels.cylinder_refine(X, N, mask, axis)
        if ok:
            axis = refined
        else:  # a singular circle system: numpy's least squares
            center, axis, radius = refine_cylinder(X[mask], N[mask], axis)
        if not r_min < radius < r_max:
            return None
    mask = kernels.cylinder_inliers(X, N, center, axis, radius, dist, cos_min)
    return Fit("cylinder", mask, center=center, axis=axis, radius=radius)


def fit_sphere(X, N, rng, dist, cos_min, r_min, r_max, hypotheses=32, subset=SUBSET) -> Fit | None:
    n = len(X)
    if n < 10:
        return None
    i, j = _pairs(rng, n, hypotheses)
    centers, radii = kernels.sphere_hypotheses(X, N, i, j, r_min, r_max)
    if len(radii) == 0:
        return None
    score = kernels.score_spheres(X, N, _subset(rng, n, subset), centers, radii, dist, cos_min)
    best = int(np.argmax(score))
    center, radius = centers[best], float(radii[best])
    for _ in range(2):
        mask = kernels.sphere_inliers(X, N, center, radius, dist, cos_min)
        if mask.sum() < 10:
            return None
        center, radius, ok = kernels.sphere_refine(X, mask)
        if not ok:
            center, radius = refine_sphere(X[mask])
        if not r_min < radius < r_max:
            return None
    mask = kernels.sphere_inliers(X, N, center, radius, dist, cos_min)
    return Fit("sphere", mask, center=center, radius=radius)


# -- is a curved fit really curved? ------------------------------------------------------------


def cylinder_arc(N: np.ndarray, axis: np.ndarray) -> float:
    """Angle (deg) the inlier normals sweep around the axis: small for a flat patch
    (compiled, linear in the points: a sort of tens of thousands of angles was ms)."""
    e1 = _unit(cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0]))
    e2 = cross(axis, e1)
    return math.degrees(kernels.normal_arc(np.ascontiguousarray(N, np.float64), e1, e2))


def sphere_spread(N: np.ndarray) -> float:
    """Smaller angular spread (deg) of the normals across their two main directions
    (compiled: one pass)."""
    return float(kernels.normal_spread(np.ascontiguousarray(N, np.float64)))


def cylinder_arc_numpy(N: np.ndarray, axis: np.ndarray) -> float:
    """``cylinder_arc`` in numpy (the reference the compiled one is tested against)."""
    e1 = _unit(cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0]))
    e2 = cross(axis, e1)
    ang = np.arctan2(N @ e2, N @ e1)
    ang = np.sort(np.mod(ang, 2 * np.pi))
    if len(ang) < 2:
        return 0.0
    gaps = np.diff(np.concatenate([ang, ang[:1] + 2 * np.pi]))
    return float(np.degrees(2 * np.pi - gaps.max()))


def sphere_spread_numpy(N: np.ndarray) -> float:
    """``sphere_spread`` in numpy (the reference)."""
    if len(N) < 3:
        return 0.0
    m = _unit(N.mean(axis=0))
    D = N - np.outer(N @ m, m)
    w = np.linalg.eigvalsh(D.T @ D / len(N))
    return float(np.degrees(np.arcsin(np.sqrt(np.clip(w[1], 0, 1)))))
