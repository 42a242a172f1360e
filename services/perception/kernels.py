"""Compiled per-pixel kernels of the organized cloud (numba): normals from box-filtered points
and the segmentation boundaries. One pass over the grid each, instead of a dozen numpy passes."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def normals(points: np.ndarray, valid: np.ndarray, radius: int, centre: np.ndarray) -> np.ndarray:
    """Unit normals (h, w, 3), facing ``centre``, as the cross product of the tangents of the
    points averaged over (2·radius + 1)² windows; 0 where unknown."""
    h, w = valid.shape
    mean = np.zeros((h, w, 3), np.float32)
    have = np.zeros((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            sx = sy = sz = 0.0
            n = 0
            for rr in range(max(0, r - radius), min(h, r + radius + 1)):
                for cc in range(max(0, c - radius), min(w, c + radius + 1)):
                    if valid[rr, cc]:
                        sx += points[rr, cc, 0]
                        sy += points[rr, cc, 1]
                        sz += points[rr, cc, 2]
                        n += 1
            mean[r, c, 0] = sx / n
            mean[r, c, 1] = sy / n
            mean[r, c, 2] = sz / n
            have[r, c] = True
    out = np.zeros((h, w, 3), np.float32)
    k = max(1, radius)
    for r in range(k, h - k):
        for c in range(k, w - k):
            if not (
                have[r, c]
                and have[r, c - k]
                and have[r, c + k]
                and have[r - k, c]
                and have[r + k, c]
            ):
                continue
            ux = mean[r, c + k, 0] - mean[r, c - k, 0]
            uy = mean[r, c + k, 1] - mean[r, c - k, 1]
            uz = mean[r, c + k, 2] - mean[r, c - k, 2]
            vx = mean[r + k, c, 0] - mean[r - k, c, 0]
            vy = mean[r + k, c, 1] - mean[r - k, c, 1]
            vz = mean[r + k, c, 2] - mean[r - k, c, 2]
            nx = uy * vz - uz * vy
            ny = uz * vx - ux * vz
            nz = ux * vy - uy * vx
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm <= 0:
                continue
            if (
                nx * (centre[0] - points[r, c, 0])
                + ny * (centre[1] - points[r, c, 1])
                + nz * (centre[2] - points[r, c, 2])
                < 0
            ):
                norm = -norm
            out[r, c, 0] = nx / norm
            out[r, c, 1] = ny / norm
            out[r, c, 2] = nz / norm
    return out


@njit(cache=True, nogil=True)
def boundaries(
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    spacing: np.ndarray,
    jump_factor: float,
    jump_abs: float,
    cos_crease: float,
    offset: int,
) -> np.ndarray:
    """(h, w) bool: the far side of depth jumps between neighbours, and the middle of concave
    creases between pixels ``offset`` apart (LCCP convexity: (n_i − n_j)·(p_i − p_j) < 0)."""
    h, w = valid.shape
    edge = np.zeros((h, w), np.bool_)
    half = offset // 2
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            for dr, dc in ((0, 1), (1, 0)):
                r2, c2 = r + dr, c + dc
                if r2 < h and c2 < w and valid[r2, c2]:
                    dx = points[r, c, 0] - points[r2, c2, 0]
                    dy = points[r, c, 1] - points[r2, c2, 1]
                    dz = points[r, c, 2] - points[r2, c2, 2]
                    limit = jump_factor * min(spacing[r, c], spacing[r2, c2]) + jump_abs
                    if dx * dx + dy * dy + dz * dz > limit * limit:
                        if spacing[r, c] > spacing[r2, c2]:
                            edge[r, c] = True
                        else:
                            edge[r2, c2] = True
                r2, c2 = r + dr * offset, c + dc * offset
                if r2 >= h or c2 >= w or not valid[r2, c2]:
                    continue
                ax, ay, az = normals[r, c, 0], normals[r, c, 1], normals[r, c, 2]
                bx, by, bz = normals[r2, c2, 0], normals[r2, c2, 1], normals[r2, c2, 2]
                if (ax == 0 and ay == 0 and az == 0) or (bx == 0 and by == 0 and bz == 0):
                    continue
                if ax * bx + ay * by + az * bz >= cos_crease:
                    continue
                convexity = (
                    (ax - bx) * (points[r, c, 0] - points[r2, c2, 0])
                    + (ay - by) * (points[r, c, 1] - points[r2, c2, 1])
                    + (az - bz) * (points[r, c, 2] - points[r2, c2, 2])
                )
                if convexity < 0:
                    if offset > 1:
                        edge[r + dr * half, c + dc * half] = True
                    else:
                        edge[r, c] = True
                        edge[r2, c2] = True
    return edge
