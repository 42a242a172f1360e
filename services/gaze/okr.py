"""Retinal slip for the optokinetic reflex (thesis 5.3; Habra et al. 2017): how fast the
fixated point drifts across the image beyond what the forward model expected.

Between two frames of a camera, sparse optical flow (pyramidal Lucas-Kanade on corners near the
target's image position) measures how the scene around the target moved in the image; the
forward model's camera poses at the two frames predict how a still target should have moved.
The difference, over the time between the frames and through the focal lengths, is the slip in
rad/s along the camera's x (right) and y (down): zero while the model is right, the part it
missed otherwise (reafference)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def project(T_world_camera: np.ndarray, K: tuple[float, float, float, float], x: np.ndarray):
    fx, fy, cx, cy = K
    c = T_world_camera[:3, :3].T @ (np.asarray(x, float) - T_world_camera[:3, 3])
    return np.array([fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy])


@dataclass
class _Frame:
    grey: np.ndarray
    T_model: np.ndarray
    stamp: float


class RetinalSlip:
    """Feed frames of one camera with the forward model's pose of it at each frame's stamp."""

    def __init__(self, intrinsics: tuple[float, float, float, float], window: int = 60,
                 min_tracks: int = 8, margin: int = 160) -> None:  # fmt: skip
        """Corners within ``window`` px of the target's image position are tracked; both
        images are cut to that window plus ``margin`` px (the motion a frame may see there)
        before corner detection and the flow's pyramids: the work is the window's, not the
        image's (on a 640 × 480 camera, 0.6 of its pixels)."""
        self.K, self.window, self.min_tracks = intrinsics, window, min_tracks
        self.margin = margin
        self.previous: _Frame | None = None

    def update(
        self, rgb: np.ndarray, T_model: np.ndarray, stamp: float, target: np.ndarray
    ) -> np.ndarray | None:
        """Slip (rad/s along the camera's x, y) of ``target`` between the previous frame and
        this one, or None (first frame, target behind the camera or off the image, too few
        corners tracked)."""
        grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
        prev, self.previous = self.previous, _Frame(grey, T_model, stamp)
        if prev is None or stamp <= prev.stamp:
            return None
        h, w = grey.shape
        uv0 = project(prev.T_model, self.K, target)
        if not np.all(np.isfinite(uv0)) or not (0 <= uv0[0] < w and 0 <= uv0[1] < h):
            return None
        u, v, r = int(uv0[0]), int(uv0[1]), self.window + self.margin
        x0, y0, x1, y1 = max(0, u - r), max(0, v - r), min(w, u + r), min(h, v + r)
        before, after = prev.grey[y0:y1, x0:x1], grey[y0:y1, x0:x1]
        mask = np.zeros_like(before)
        mask[max(0, v - self.window - y0) : v + self.window - y0,
             max(0, u - self.window - x0) : u + self.window - x0] = 255  # fmt: skip
        corners = cv2.goodFeaturesToTrack(before, 60, 0.01, 5, mask=mask)
        if corners is None or len(corners) < self.min_tracks:
            return None
        moved, ok, _ = cv2.calcOpticalFlowPyrLK(before, after, corners, None,
                                                winSize=(21, 21), maxLevel=3)  # fmt: skip
        ok = ok.ravel() == 1
        if ok.sum() < self.min_tracks:
            return None
        measured = np.median((moved - corners).reshape(-1, 2)[ok], axis=0)
        predicted = project(T_model, self.K, target) - uv0
        dt = stamp - prev.stamp
        fx, fy = self.K[0], self.K[1]
        return (measured - predicted) / dt / np.array([fx, fy])
