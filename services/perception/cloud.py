"""The frame as an organized point cloud in world coordinates, with smoothed normals.

Working on the image grid (like CAPE / PEAC) keeps every neighbourhood free: neighbours are
pixels, smoothing is a box filter, clusters are connected components. ``stride`` subsamples
the image first (2: 640×480 → 320×240).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.perception import kernels


@dataclass
class OrganizedCloud:
    """Grid-shaped arrays of one frame (h × w after striding)."""

    points: np.ndarray  # (h, w, 3) float32 world coordinates, NaN where invalid
    normals: np.ndarray  # (h, w, 3) float32 unit normals facing the camera, 0 where unknown
    valid: np.ndarray  # (h, w) bool: a depth reading inside the range
    colours: np.ndarray  # (h, w, 3) uint8
    spacing: np.ndarray  # (h, w) float32: distance between neighbouring grid points, m
    camera_centre: np.ndarray  # (3,) world position of the optical centre
    #: (h, w) int32: the half-width (grid steps) of the window each normal was averaged over
    radius: np.ndarray | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.valid.shape

    @property
    def size(self) -> int:
        return self.valid.size

    def labels(self, pixels: np.ndarray) -> tuple[np.ndarray, int]:
        """The 8-connected components of ``pixels`` (flat grid indices): labels 1 … k, k."""
        return kernels.grid_labels(pixels, self.shape[1])

    def near(self, pixels: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Which of ``pixels`` are within one grid step of a ``mask``-ed one."""
        return kernels.near(pixels, mask, self.shape[1])

    def viewing_distance(self, pixels: np.ndarray) -> float:
        """Median distance from the pixels' points to the camera (the noise scale)."""
        return kernels.view_median(
            self.points.reshape(-1, 3), np.asarray(pixels, np.int64), self.camera_centre
        )

    def viewer(self, pixels: np.ndarray) -> np.ndarray:
        """Where the pixels were seen from: the camera."""
        return self.camera_centre


def organized_cloud(
    depth: np.ndarray,
    rgb: np.ndarray | None,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    T_world_camera: np.ndarray,
    *,
    depth_min: float = 0.35,
    depth_max: float = 3.0,
    stride: int = 2,
    smooth: int = 3,
    smooth_per_m2: float = 0.0,
) -> OrganizedCloud:
    """Back-project ``depth`` (metres along the optical axis; 0, NaN or out-of-range are
    masked) into world coordinates, and estimate normals from box-filtered points: over a
    ``smooth``-wide window, or, with ``smooth_per_m2``, one whose half-width grows as
    round(smooth_per_m2 · z²) grid steps where that is more (structured-light depth comes
    in steps that grow with z²: 18 mm at 2.5 m on a Kinect v1, where a 3-wide window's
    normals flip from step to step and every step looks like a crease)."""
    z = np.asarray(depth, dtype=np.float32)[::stride, ::stride]
    h, w = z.shape
    valid = np.isfinite(z) & (z >= depth_min) & (z <= depth_max)
    z = np.where(valid, z, np.float32(0))
    R = T_world_camera[:3, :3].astype(np.float32)
    t = T_world_camera[:3, 3].astype(np.float32)
    points = kernels.back_project(z, valid, fx, fy, cx, cy, stride, R, t)
    # a writable C-ordered copy: the kernels then see one array type whether the image came
    # decoded from a message (read-only) or not, and the warm-up compiled that type
    colours = (
        np.array(np.asarray(rgb)[::stride, ::stride], np.uint8, order="C")
        if rgb is not None
        else np.zeros((h, w, 3), np.uint8)
    )
    spacing = (stride * z / np.float32(fx)).astype(np.float32)
    centre = T_world_camera[:3, 3].astype(np.float32)
    radius = np.full((h, w), smooth // 2, np.int32)
    if smooth_per_m2 > 0:
        np.maximum(radius, np.rint(np.float32(smooth_per_m2) * z * z).astype(np.int32), out=radius)
    normals = kernels.normals(points, valid, radius, centre)
    return OrganizedCloud(
        points, normals, valid, colours, spacing, T_world_camera[:3, 3].copy(), radius
    )
