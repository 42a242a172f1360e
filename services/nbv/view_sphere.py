"""The view sphere (thesis 4.1, 4.2.1): candidate camera poses on the upper half of a sphere of
radius r around a centre, optical axis through the centre, no roll (Eq. 4.1), and the platform
pose of a view (Eq. 4.2, 4.3)."""

from __future__ import annotations

import math

import numpy as np

UP = np.array([0.0, 0.0, 1.0])


def spherical(r: float, theta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Eq. 4.4: (r, θ polar, φ azimuth) → (x, y, z), one row per sample."""
    theta, phi = np.asarray(theta, float), np.asarray(phi, float)
    return r * np.column_stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)]
    )


def equidistant(k: int, r: float = 1.5) -> np.ndarray:
    """Views on the grid (θ, φ) = (2πm/k, 2πn/k) (4.2.1) with 0 < θ < π/2 (upper half, z > 0),
    0 ≤ φ < 2π: the sphere points relative to its centre."""
    step = 2 * math.pi / k
    thetas = [m * step for m in range(1, k) if m * step < math.pi / 2]
    phis = [n * step for n in range(k)]
    theta, phi = np.meshgrid(thetas, phis, indexing="ij")
    return spherical(r, theta.ravel(), phi.ravel())


def random(n: int, rng: np.random.Generator, r: float = 1.5, upper: bool = True) -> np.ndarray:
    """Uniform on the sphere: φ = 2πu_φ, θ = arccos(2u_θ − 1) (4.2.1). With ``upper`` the
    samples are reflected into the upper half (|z|), which keeps them uniform there."""
    phi = 2 * math.pi * rng.uniform(size=n)
    theta = np.arccos(2 * rng.uniform(size=n) - 1)
    t = spherical(r, theta, phi)
    if upper:
        t[:, 2] = np.abs(t[:, 2])
    return t


def view_pose(centre: np.ndarray, t: np.ndarray) -> np.ndarray:
    """T_world_camera of the view at ``centre + t`` (Eq. 4.1): optical axis (z) towards the
    centre, x right and level (no roll), y down. Optical frame: x right, y down, z forward."""
    z = -np.asarray(t, float) / np.linalg.norm(t)
    x = np.cross(z, UP)
    if np.linalg.norm(x) < 1e-9:  # straight down: any level x will do
        x = np.array([0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    T[:3, 3] = np.asarray(centre, float) + t
    return T


def platform_pose(centre: np.ndarray, t: np.ndarray) -> tuple[float, float, float]:
    """Eq. 4.2, 4.3: the platform stands under the view, (x, y) = (t1, t2) (plus the centre),
    and faces the centre. With AVS's platform convention (forward = +x) the heading is
    atan2(−t2, −t1); the thesis writes it for ARMAR's (forward = +y) as −π/2 + atan2(·)."""
    c = np.asarray(centre, float)
    return float(c[0] + t[0]), float(c[1] + t[1]), math.atan2(-t[1], -t[0])


def wrap(angle: float | np.ndarray) -> float | np.ndarray:
    """Δ of Eq. 4.7: an angle (difference) confined to (−π, π]."""
    return np.arctan2(np.sin(angle), np.cos(angle))
