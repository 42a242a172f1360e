"""Predicted information gain (thesis 4.3.1, Eq. 4.6): cast the camera's pixel rays from a view
through the occupancy map and count the unknown voxels each ray traverses before its first
occupied voxel, within sensor range. Hierarchical (Vasquez-Gomez et al. 2014): every 30th ray
for all candidates, then every ray for the best k.

The map arrives as voxel states (uint8: 0 unknown, 1 free, 2 occupied, the scene memory's
``memory/occupancy/slice``). One numba kernel walks the rays (3D DDA), views in parallel."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
from numba import njit, prange

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


@njit(cache=True, nogil=True, inline="always")
def _axis(p, u, voxel, i):
    if u > 1e-12:
        return 1, ((i + 1) * voxel - p) / u, voxel / u
    if u < -1e-12:
        return -1, (i * voxel - p) / u, -voxel / u
    return 1, 1e30, 1e30


@njit(cache=True, nogil=True)
def _clip(o, u, lo, hi, t0, t1):
    """The parameter interval of the ray o + t·u inside the box [lo, hi), within [t0, t1]."""
    for a in range(3):
        if abs(u[a]) < 1e-12:
            if o[a] < lo[a] or o[a] >= hi[a]:
                return 1.0, 0.0
        else:
            ta, tb = (lo[a] - o[a]) / u[a], (hi[a] - o[a]) / u[a]
            if ta > tb:
                ta, tb = tb, ta
            t0, t1 = max(t0, ta), min(t1, tb)
    return t0, t1


@njit(cache=True, nogil=True)
def ray_gain(states, origin, voxel, o, u, max_range, box_lo, box_hi):
    """Unknown voxels inside the box [box_lo, box_hi) (world) on one ray from ``o`` along the
    unit ``u`` before its first occupied voxel, within ``max_range`` (map frame: ``origin`` at
    the grid's corner). A ray that misses the box costs nothing; one that leaves it stops."""
    nx, ny, nz = states.shape
    r0, r1 = _clip(o, u, box_lo, box_hi, 0.0, max_range)
    if r0 >= r1:
        return 0
    b0x = math.floor((box_lo[0] - origin[0]) / voxel + 1e-9)
    b0y = math.floor((box_lo[1] - origin[1]) / voxel + 1e-9)
    b0z = math.floor((box_lo[2] - origin[2]) / voxel + 1e-9)
    b1x = math.ceil((box_hi[0] - origin[0]) / voxel - 1e-9)
    b1y = math.ceil((box_hi[1] - origin[1]) / voxel - 1e-9)
    b1z = math.ceil((box_hi[2] - origin[2]) / voxel - 1e-9)
    # clip the segment [0, min(max_range, leaving the box)] to the grid's box
    t0, t1 = 0.0, r1
    for a in range(3):
        n = nx if a == 0 else (ny if a == 1 else nz)
        p = o[a] - origin[a]
        if abs(u[a]) < 1e-12:
            if p < 0 or p >= n * voxel:
                return 0
        else:
            ta, tb = -p / u[a], (n * voxel - p) / u[a]
            if ta > tb:
                ta, tb = tb, ta
            t0, t1 = max(t0, ta), min(t1, tb)
    if t0 >= t1:
        return 0
    px = o[0] - origin[0] + u[0] * (t0 + 1e-9)
    py = o[1] - origin[1] + u[1] * (t0 + 1e-9)
    pz = o[2] - origin[2] + u[2] * (t0 + 1e-9)
    inv = 1.0 / voxel
    ix = min(max(int(px * inv), 0), nx - 1)
    iy = min(max(int(py * inv), 0), ny - 1)
    iz = min(max(int(pz * inv), 0), nz - 1)
    sx, tmx, tdx = _axis(px, u[0], voxel, ix)
    sy, tmy, tdy = _axis(py, u[1], voxel, iy)
    sz, tmz, tdz = _axis(pz, u[2], voxel, iz)
    limit = t1 - t0
    count = 0
    t = 0.0
    while t <= limit:
        s = states[ix, iy, iz]
        if s == OCCUPIED:
            break
        if s == UNKNOWN and b0x <= ix < b1x and b0y <= iy < b1y and b0z <= iz < b1z:
            count += 1
        cx = tmx <= tmy and tmx <= tmz
        cy = not cx and tmy <= tmz
        if cx:
            t = tmx
            ix += sx
            tmx += tdx
        elif cy:
            t = tmy
            iy += sy
            tmy += tdy
        else:
            t = tmz
            iz += sz
            tmz += tdz
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            break
    return count


@njit(cache=True, nogil=True, parallel=True)
def _gains(states, origin, voxel, poses, dirs, max_range, box_lo, box_hi, out):
    """out[v] = Σ over the rays ``dirs`` (camera frame, unit) of view ``poses[v]``."""
    for v in prange(poses.shape[0]):
        R = poses[v, :3, :3]
        o = poses[v, :3, 3].copy()
        total = 0
        u = np.empty(3)
        for r in range(dirs.shape[0]):
            d = dirs[r]
            u[0] = R[0, 0] * d[0] + R[0, 1] * d[1] + R[0, 2] * d[2]
            u[1] = R[1, 0] * d[0] + R[1, 1] * d[1] + R[1, 2] * d[2]
            u[2] = R[2, 0] * d[0] + R[2, 1] * d[1] + R[2, 2] * d[2]
            total += ray_gain(states, origin, voxel, o, u, max_range, box_lo, box_hi)
        out[v] = total


def pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float, every: int = 1):
    """Unit ray directions (camera optical frame) of every ``every``-th pixel, row-major:
    every = 30 keeps 10,240 of 640×480 (the thesis's 4.3.1)."""
    v, u = np.divmod(np.arange(0, width * height, every), width)
    d = np.column_stack([(u - cx) / fx, (v - cy) / fy, np.ones(len(u))])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def information_gain(
    states: np.ndarray,
    origin: np.ndarray,
    voxel: float,
    poses: np.ndarray,
    rays: np.ndarray,
    max_range: float = 3.0,
    box: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """IG(v) (Eq. 4.6) of each view ``poses[v]`` (T_world_camera) for the camera ``rays``,
    counting the unknown voxels inside ``box`` (default: the whole map), e.g. the scene's roi."""
    origin = np.asarray(origin, np.float64)
    if box is None:
        box = (origin, origin + np.array(states.shape) * voxel)
    # the voxels the box touches: snapped outwards to the grid
    box = (
        origin + np.floor((np.asarray(box[0]) - origin) / voxel + 1e-9) * voxel,
        origin + np.ceil((np.asarray(box[1]) - origin) / voxel - 1e-9) * voxel,
    )
    poses = np.ascontiguousarray(np.asarray(poses, np.float64).reshape(-1, 4, 4))
    out = np.zeros(len(poses), np.int64)
    if len(poses):
        _gains(
            np.ascontiguousarray(states, dtype=np.uint8),
            origin,
            float(voxel),
            poses,
            np.ascontiguousarray(rays, np.float64),
            float(max_range),
            np.asarray(box[0], np.float64),
            np.asarray(box[1], np.float64),
            out,
        )
    return out


def hierarchical(
    states: np.ndarray,
    origin: np.ndarray,
    voxel: float,
    poses: np.ndarray,
    intrinsics: tuple[int, int, float, float, float, float],
    max_range: float = 3.0,
    every: int = 30,
    best_k: int = 3,
    box: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(IG of every view, the indices of the best k, whose IG is then from every ray). The
    coarse IG is scaled by ``every`` so that both are on one scale."""
    coarse = information_gain(
        states, origin, voxel, poses, pixel_rays(*intrinsics, every), max_range, box
    )
    gains = coarse.astype(np.float64) * every
    if best_k <= 0 or not len(poses):
        return gains, np.zeros(0, int)
    best = np.argsort(-coarse, kind="stable")[: min(best_k, len(poses))]
    fine = information_gain(
        states, origin, voxel, poses[best], pixel_rays(*intrinsics, 1), max_range, box
    )
    gains[best] = fine
    return gains, best


def brute_force_gain(states, origin, voxel, T, direction, max_range, box=None) -> int:
    """Reference for the tests, by another route than the DDA: every crossing of the ray with
    a voxel boundary plane, sorted; each piece between two crossings lies in one voxel (its
    midpoint tells which). Counts the unknown voxels before the first occupied one."""
    o, u = T[:3, 3] - origin, T[:3, :3] @ direction
    ts = [0.0, max_range]
    for a in range(3):
        if abs(u[a]) > 1e-12:
            k = np.arange(states.shape[a] + 1) * voxel
            t = (k - o[a]) / u[a]
            ts += [x for x in t if 0 < x < max_range]
    ts = np.unique(ts)
    if box is not None:  # the voxels the box touches
        b0 = np.floor((np.asarray(box[0]) - origin) / voxel + 1e-9)
        b1 = np.ceil((np.asarray(box[1]) - origin) / voxel - 1e-9)

    def inside(k: np.ndarray) -> bool:
        return box is None or bool(np.all((k >= b0) & (k < b1)))

    count = 0
    for t0, t1 in pairwise(ts):
        k = np.floor((o + u * (t0 + t1) / 2) / voxel).astype(int)
        if np.any(k < 0) or np.any(k >= states.shape):
            continue
        if states[tuple(k)] == OCCUPIED:
            break
        count += inside(k) and states[tuple(k)] == UNKNOWN
    return int(count)


__all__ = ["brute_force_gain", "hierarchical", "information_gain", "pixel_rays", "ray_gain"]
