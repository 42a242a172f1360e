"""Retinal slip for the optokinetic reflex (thesis 5.3; Habra et al. 2017): how fast the
fixated point drifts across the image beyond what the forward model expected.

Between two frames of a camera, sparse optical flow (pyramidal Lucas-Kanade on corners near the
target's image position) measures how the scene around the target moved in the image; the
forward model's camera poses at the two frames predict how each tracked point, still in the
world, should have moved. The median difference, over the time between the frames and through
the focal lengths, is the slip in rad/s along the camera's x (right) and y (down): zero while
the model is right, the part it missed otherwise (reafference).

Each point is predicted at its own depth where the camera measures depth (an RGB-D camera),
else at the target's: while the platform translates, points nearer or farther than the target
move across the image faster or slower than it (parallax), and predicting them all at the
target's depth reads that parallax as slip (on the live stack's sideways drive it held the
gaze 0.4° off the target at the median, against 0.16° without OKR)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


def project(T_world_camera: np.ndarray, K: tuple[float, float, float, float], x: np.ndarray):
    fx, fy, cx, cy = K
    c = T_world_camera[:3, :3].T @ (np.asarray(x, float) - T_world_camera[:3, 3])
    return np.array([fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy])


def project_all(T_world_camera: np.ndarray, K: tuple[float, float, float, float], X: np.ndarray):
    """Pixels (n × 2) of world points X (n × 3); points behind the camera come out non-finite."""
    fx, fy, cx, cy = K
    c = (np.asarray(X, float) - T_world_camera[:3, 3]) @ T_world_camera[:3, :3]
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(c[:, 2] > 1e-6, c[:, 2], np.nan)
        return np.column_stack([fx * c[:, 0] / z + cx, fy * c[:, 1] / z + cy])


@dataclass
class _Frame:
    grey: np.ndarray
    T_model: np.ndarray
    stamp: float
    depth: np.ndarray | None = None  # metres along the optical axis, 0: none


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
        self,
        rgb: np.ndarray,
        T_model: np.ndarray,
        stamp: float,
        target: np.ndarray,
        depth: np.ndarray | None = None,
    ) -> np.ndarray | None:
        """Slip (rad/s along the camera's x, y) of ``target`` between the previous frame and
        this one, or None (first frame, target behind the camera or off the image, too few
        corners tracked). ``depth``: the frame's depth image, if the camera has one."""
        grey = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY)
        prev, self.previous = self.previous, _Frame(grey, T_model, stamp, depth)
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
        start = corners.reshape(-1, 2)[ok] + (x0, y0)  # full-image pixels
        end = moved.reshape(-1, 2)[ok] + (x0, y0)
        predicted = self.predicted(prev, T_model, start, target)
        residual = end - predicted
        residual = residual[np.all(np.isfinite(residual), axis=1)]
        if len(residual) < self.min_tracks:
            return None
        dt = stamp - prev.stamp
        fx, fy = self.K[0], self.K[1]
        return np.median(residual, axis=0) / dt / np.array([fx, fy])

    def predicted(
        self, prev: _Frame, T_model: np.ndarray, pixels: np.ndarray, target: np.ndarray
    ) -> np.ndarray:
        """Where the forward model puts the still world points seen at ``pixels`` of the
        previous frame in this one: each at its measured depth, or (no depth there) at the
        target's depth along the optical axis."""
        fx, fy, cx, cy = self.K
        T0 = prev.T_model
        z_target = float((np.asarray(target, float) - T0[:3, 3]) @ T0[:3, 2])
        z = np.full(len(pixels), z_target)
        if prev.depth is not None:
            h, w = prev.depth.shape
            u = np.clip(np.rint(pixels[:, 0]).astype(int), 0, w - 1)
            v = np.clip(np.rint(pixels[:, 1]).astype(int), 0, h - 1)
            measured = prev.depth[v, u].astype(float)
            z = np.where(measured > 0, measured, z)
        rays = np.column_stack([(pixels[:, 0] - cx) / fx, (pixels[:, 1] - cy) / fy,
                                np.ones(len(pixels))])  # fmt: skip
        X = T0[:3, 3] + (rays * z[:, None]) @ T0[:3, :3].T
        return project_all(T_model, self.K, X)
