"""Saliency sources of the ego-sphere (thesis 5.1.1): the uncertainty of object localisation
(Welke et al. 2013) and single-coloured blobs in the peripheral image (5.4.2).

An object's position belief is a Kalman filter (constant position, process noise growing the
covariance while it is not looked at); its saliency is the differential entropy of the belief
above what the task needs: σ = det(Σ)^(1/6) (Eq. 5.2), u = ½·ln((2πe·σ²)³) (Eq. 5.3), the
task acuity b = ½·ln((2πe·α²)³) (Eq. 5.4), s = max(0, u − b)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

TWO_PI_E = 2.0 * np.pi * np.e


def entropy(sigma: float) -> float:
    """½·ln((2πe·σ²)³): Eq. 5.3 (of a belief) and 5.4 (of the task acuity α)."""
    return 0.5 * np.log(TWO_PI_E**3 * sigma**6)


@dataclass
class ObjectBelief:
    """Kalman filter on an object's position (world, m)."""

    mean: np.ndarray
    covariance: np.ndarray
    acuity: float = 0.01  # α: the localisation accuracy the task needs (m)
    process_noise: float = 2e-6  # m²/s added to each variance: ~20 s unseen and 8 mm is 1 cm
    stamp: float = 0.0
    observations: int = field(default=0)

    @classmethod
    def first(cls, position, covariance, stamp: float, acuity: float = 0.01) -> ObjectBelief:
        return cls(
            np.asarray(position, float), np.asarray(covariance, float), acuity, stamp=stamp,
            observations=1,
        )  # fmt: skip

    def predict(self, stamp: float) -> None:
        dt = max(0.0, stamp - self.stamp)
        self.covariance = self.covariance + self.process_noise * dt * np.eye(3)
        self.stamp = max(self.stamp, stamp)

    def update(self, position, covariance, stamp: float) -> None:
        """Fuse one localisation result (its position and covariance)."""
        self.predict(stamp)
        S = self.covariance + np.asarray(covariance, float)
        K = self.covariance @ np.linalg.inv(S)
        self.mean = self.mean + K @ (np.asarray(position, float) - self.mean)
        self.covariance = (np.eye(3) - K) @ self.covariance
        self.covariance = (self.covariance + self.covariance.T) / 2
        self.observations += 1

    @property
    def sigma(self) -> float:
        """σ = det(Σ)^(1/6) (Eq. 5.2)."""
        return float(np.linalg.det(self.covariance) ** (1.0 / 6.0))

    @property
    def saliency(self) -> float:
        """s = max(0, u − b) (Eq. 5.3, 5.4)."""
        return max(0.0, entropy(self.sigma) - entropy(self.acuity))


def colour_blobs(
    rgb: np.ndarray,
    min_saturation: float = 0.5,
    min_value: float = 0.25,
    min_pixels: int = 50,
    step: int = 2,
    most: int = 8,
) -> list[tuple[float, float, int]]:
    """Single-coloured blobs: connected regions of saturated pixels (HSV saturation and value
    above the thresholds) of one hue (12 bins of 30°), as (u, v, pixels) of their centres in
    full-image pixels, the ``most`` largest. Found on every ``step``-th pixel (peripheral
    attention needs no more; OpenCV, a few ms per VGA frame, releasing the GIL)."""
    small = np.ascontiguousarray(rgb[step // 2 :: step, step // 2 :: step])
    hsv = cv2.cvtColor(small, cv2.COLOR_RGB2HSV)  # H in [0, 180): 15 per 30° bin
    mask = (hsv[..., 1] >= min_saturation * 255) & (hsv[..., 2] >= min_value * 255)
    if not mask.any():
        return []
    bins = hsv[..., 0] // 15
    least = max(1, math.ceil(min_pixels / step**2))
    blobs = []
    for h in np.unique(bins[mask]):
        one = (mask & (bins == h)).astype(np.uint8)
        n, _, stats, centres = cv2.connectedComponentsWithStats(one, connectivity=4)
        for k in range(1, n):
            size = int(stats[k, cv2.CC_STAT_AREA])
            if size >= least:
                u, v = centres[k] * step + step // 2
                blobs.append((float(u), float(v), size * step**2))
    return sorted(blobs, key=lambda b: -b[2])[:most]


def pixel_rays(
    uv: np.ndarray, intrinsics: tuple[float, float, float, float], T_world_camera: np.ndarray
) -> np.ndarray:
    """World unit directions of the rays through pixels ``uv`` (n × 2) of a pinhole camera."""
    fx, fy, cx, cy = intrinsics
    uv = np.atleast_2d(np.asarray(uv, float))
    d = np.column_stack([(uv[:, 0] - cx) / fx, (uv[:, 1] - cy) / fy, np.ones(len(uv))])
    d = d @ np.asarray(T_world_camera)[:3, :3].T
    return d / np.linalg.norm(d, axis=1, keepdims=True)
