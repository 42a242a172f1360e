"""What the grasping-while-moving experiment sees (thesis 5.4.2): single-coloured blobs by HSV
segmentation, located in 3D from the two cameras of a stereo pair (the foveal pair localises the
cup and the hand's marker, the peripheral pair finds blobs that draw the gaze), with the
covariance of the triangulated point from the pixel noise (Σ = σ²·J·Jᵀ, J the point's
derivative by the four image coordinates) for the Kalman filters of ``ObjectBelief``."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

#: OpenCV hue ranges (0–180) of the colours in the experiment's scene
HUES: dict[str, tuple[tuple[int, int], ...]] = {
    "green": ((45, 85),),
    "red": ((0, 8), (172, 180)),
    "blue": ((100, 130),),
    "yellow": ((20, 35),),
}


@dataclass(frozen=True)
class Blob:
    area: float  # px
    centre: np.ndarray  # (u, v)
    fill: float  # area over its bounding box's: a sharp compact object ~0.8, a smeared one less
    touches_border: bool


def find_blob(
    rgb: np.ndarray,
    colour: str,
    min_area: float = 60.0,
    min_saturation: int = 100,
    min_value: int = 50,
) -> Blob | None:
    """The largest region of one colour (HSV segmentation), or None under ``min_area``."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV)
    mask = np.zeros(hsv.shape[:2], np.uint8)
    for lo, hi in HUES[colour]:
        low = np.array([lo, min_saturation, min_value], np.uint8)
        mask |= cv2.inRange(hsv, low, np.array([hi, 255, 255], np.uint8))
    n, _, stats, centres = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n <= 1:
        return None
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h, area = (int(v) for v in stats[k])
    if area < min_area:
        return None
    H, W = mask.shape
    border = x <= 0 or y <= 0 or x + w >= W or y + h >= H
    return Blob(float(area), centres[k].astype(float), area / float(w * h), border)


def _ray(uv: np.ndarray, K: np.ndarray, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = T[:3, :3] @ np.array([(uv[0] - K[0, 2]) / K[0, 0], (uv[1] - K[1, 2]) / K[1, 1], 1.0])
    return T[:3, 3], d / np.linalg.norm(d)


def triangulate(
    uv_left: np.ndarray, uv_right: np.ndarray, K_left, K_right, T_left, T_right
) -> tuple[np.ndarray, float]:
    """(the midpoint of the two rays' closest approach, their distance there in m)."""
    p1, d1 = _ray(np.asarray(uv_left, float), K_left, T_left)
    p2, d2 = _ray(np.asarray(uv_right, float), K_right, T_right)
    w = p1 - p2
    b = d1 @ d2
    den = 1.0 - b * b
    if den < 1e-12:
        return p1 + d1, np.inf
    s = (b * (d2 @ w) - (d1 @ w)) / den
    t = ((d2 @ w) - b * (d1 @ w)) / den
    a, c = p1 + s * d1, p2 + t * d2
    if s <= 0 or t <= 0:
        return (a + c) / 2, np.inf
    return (a + c) / 2, float(np.linalg.norm(a - c))


def localise(
    uv_left, uv_right, K_left, K_right, T_left, T_right, sigma_px: float = 1.0
) -> tuple[np.ndarray, np.ndarray, float]:
    """(point, its covariance, rays' gap): the stereo point and σ_px² · J·Jᵀ, J the point's
    derivative by (u_l, v_l, u_r, v_r) by central differences."""
    x = np.array([*uv_left, *uv_right], float)
    point, gap = triangulate(x[:2], x[2:], K_left, K_right, T_left, T_right)
    J = np.empty((3, 4))
    for i in range(4):
        dx = np.zeros(4)
        dx[i] = 0.5
        a, _ = triangulate(*np.split(x + dx, 2), K_left, K_right, T_left, T_right)
        b, _ = triangulate(*np.split(x - dx, 2), K_left, K_right, T_left, T_right)
        J[:, i] = (a - b) / 1.0
    return point, sigma_px**2 * J @ J.T, gap


def silhouette_area(
    kind: str, size: tuple[float, ...], point: np.ndarray, T_camera: np.ndarray, K: np.ndarray
) -> float:
    """Pixels an upright object of known shape covers seen from the camera at ``point``: a
    sphere (r,) or an upright cylinder (r, half height), whose side and top show by the angle
    the camera looks down at it (the object model the thesis's localisation relies on)."""
    to = np.asarray(point, float) - T_camera[:3, 3]
    z = float(to @ T_camera[:3, 2])
    scale = K[0, 0] * K[1, 1] / (z * z)
    if kind == "sphere":
        return math.pi * size[0] ** 2 * scale
    down = math.asin(min(1.0, max(0.0, -to[2] / float(np.linalg.norm(to)))))
    r, h = size[0], 2 * size[1]
    return (2 * r * h * math.cos(down) + math.pi * r * r * math.sin(down)) * scale


@dataclass(frozen=True)
class StereoCheck:
    """When a pair of blobs is the object: both big enough, neither cut by the border, compact,
    of similar area, rays that meet, and an area near what the object's model covers at that
    distance (motion blur washes a colour out: what is left is a smaller, thinner blob)."""

    min_fill: float = 0.55
    max_area_ratio: float = 1.6  # between the two cameras, and against the model's
    max_gap: float = 0.01  # m

    def accepts(
        self,
        left: Blob | None,
        right: Blob | None,
        gap: float | None = None,
        expected: tuple[float, float] | None = None,
    ) -> bool:
        """``expected``: the model's area in the left and right image, once triangulated."""
        if left is None or right is None or left.touches_border or right.touches_border:
            return False
        if min(left.fill, right.fill) < self.min_fill:
            return False
        if max(left.area, right.area) > self.max_area_ratio * min(left.area, right.area):
            return False
        if expected is not None:
            k = self.max_area_ratio
            for blob, area in zip((left, right), expected, strict=True):
                if not area / k <= blob.area <= area * k:
                    return False
        return gap is None or gap <= self.max_gap
