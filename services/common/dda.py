"""The 3D DDA of Amanatides & Woo, shared by the ray casting of the scene memory (occupancy
integration) and the planner (information gain): numba helpers, inlined where they are used."""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True, inline="always")
def dda_axis(p, u, voxel, i):
    """DDA set-up along one axis from the point p (grid frame) in voxel i, ray direction u:
    (step, parameter to the next voxel boundary, parameter per voxel)."""
    if u > 1e-12:
        return 1, ((i + 1) * voxel - p) / u, voxel / u
    if u < -1e-12:
        return -1, (i * voxel - p) / u, -voxel / u
    return 1, 1e30, 1e30
