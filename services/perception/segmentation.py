"""Segmentation into disjoint regions (thesis A.6), LCCP-like, on the image grid.

Neighbouring pixels belong together unless the surface jumps between them (3D distance far
beyond the grid spacing) or they meet at a concave crease (normals differ by more than
``crease_deg`` and (n_i − n_j)·(p_i − p_j) < 0, the convexity criterion of LCCP). Convex
creases — the edges of a box — do not cut, so an object stays one region while it is cut off
the table it stands on. Regions are the connected components of what is left.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from services.perception import kernels
from services.perception.cloud import OrganizedCloud


def boundaries(
    cloud: OrganizedCloud,
    *,
    jump_factor: float = 6.0,
    jump_abs: float = 0.01,
    crease_deg: float = 30.0,
    offset: int = 2,
) -> np.ndarray:
    """(h, w) bool: pixels on a depth jump (its far side) or a concave crease."""
    return kernels.boundaries(
        cloud.points,
        cloud.normals,
        cloud.valid,
        cloud.spacing,
        jump_factor,
        jump_abs,
        float(np.cos(np.radians(crease_deg))),
        offset,
    )


def segment(cloud: OrganizedCloud, min_size: int = 30, **kwargs) -> tuple[np.ndarray, int]:
    """Labels (h, w) int32, -1 outside every region, and the number of regions (each at least
    ``min_size`` pixels), largest first."""
    inside = cloud.valid & ~boundaries(cloud, **kwargs)
    labels, n = ndimage.label(inside)
    if n == 0:
        return np.full(labels.shape, -1, np.int32), 0
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    sizes[0] = 0
    order = np.argsort(-sizes)
    keep = order[sizes[order] >= min_size]
    remap = np.full(n + 1, -1, np.int32)
    remap[keep] = np.arange(len(keep), dtype=np.int32)
    return remap[labels], len(keep)
