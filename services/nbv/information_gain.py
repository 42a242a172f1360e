"""Predicted information gain (thesis 4.3.1, Eq. 4.6): cast the camera's pixel rays from a view
through the occupancy map and count the unknown voxels each ray traverses before its first
occupied voxel, within sensor range. Hierarchical (Vasquez-Gomez et al. 2014): every 30th ray
for all candidates, then every ray for the best k.

The map arrives as voxel states (uint8: 0 unknown, 1 free, 2 occupied, the scene memory's
``memory/occupancy/slice``). One numba kernel walks the rays (3D DDA), views in parallel."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from numba import njit, prange

from services.common.dda import dda_axis

UNKNOWN, FREE, OCCUPIED = 0, 1, 2


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


BLOCK = 8  # voxels per side of a block of the skip map
ALL_UNKNOWN, ALL_FREE, MIXED = 0, 1, 2


@njit(cache=True, nogil=True, parallel=True)
def _codes(states, shift):
    nx, ny, nz = states.shape
    size = 1 << shift
    bx, by, bz = (nx + size - 1) >> shift, (ny + size - 1) >> shift, (nz + size - 1) >> shift
    codes = np.empty((bx, by, bz), np.uint8)
    for i in prange(bx):
        for j in range(by):
            for k in range(bz):
                first = states[i * size, j * size, k * size]
                code = first if first != OCCUPIED else MIXED
                for x in range(i * size, min(i * size + size, nx)):
                    if code == MIXED:
                        break
                    for y in range(j * size, min(j * size + size, ny)):
                        for z in range(k * size, min(k * size + size, nz)):
                            if states[x, y, z] != first:
                                code = MIXED
                codes[i, j, k] = code
    return codes


@njit(cache=True, nogil=True, parallel=True)
def blocked(states):
    """The states in 8×8×8 blocks of 512 contiguous bytes: a ray that crosses a block stays in
    a few cache lines (in C order every step along x or y is a new line). Voxels past the
    grid's edge are unknown; nothing reads them."""
    nx, ny, nz = states.shape
    bx, by, bz = (nx + 7) >> 3, (ny + 7) >> 3, (nz + 7) >> 3
    out = np.zeros(bx * by * bz * 512, np.uint8)
    for x in prange(nx):
        for y in range(ny):
            row = (((x >> 3) * by + (y >> 3)) * bz) << 9
            local = ((x & 7) << 6) | ((y & 7) << 3)
            for z in range(nz):
                out[row + ((z >> 3) << 9) + local + (z & 7)] = states[x, y, z]
    return out


@njit(cache=True, nogil=True, inline="always")
def _at(grid, ix, iy, iz, by, bz):
    block = ((ix >> 3) * by + (iy >> 3)) * bz + (iz >> 3)
    return grid[(block << 9) | ((ix & 7) << 6) | ((iy & 7) << 3) | (iz & 7)]


def block_codes(states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Skip maps of 8³ and 32³ blocks: ALL_UNKNOWN, ALL_FREE, or MIXED (occupied voxels, or
    both): a ray crosses a uniform block in one step, a large one first."""
    states = np.ascontiguousarray(states, dtype=np.uint8)
    return _codes(states, 3), _codes(states, 5)


@njit(cache=True, nogil=True, inline="always")
def _steps_left(i, s, n, shift):
    """Voxel steps along one axis before leaving the block (2^shift voxels) of voxel i."""
    start = (i >> shift) << shift
    if s > 0:
        return min(start + (1 << shift), n) - 1 - i
    return i - start


@njit(cache=True, nogil=True, inline="always")
def _crossings(tm, inv_td, limit, cap):
    """Boundary crossings tm, tm + td, … strictly before ``limit``, at most ``cap``
    (``inv_td`` = 1 / td: a multiplication, not a division, on the hot path)."""
    if tm >= limit:
        return 0
    return min(int((limit - tm) * inv_td) + 1, cap)


@njit(cache=True, nogil=True)
def ray_gain(
    grid, shape, codes8, codes32, origin, grid_hi, voxel, o, u, max_range, box_lo, box_hi, roi
):
    """Unknown voxels of the roi (voxel index box ``roi`` = x0, y0, z0, x1, y1, z1; the box
    [box_lo, box_hi) in the world) on one ray from ``o`` along the unit ``u`` before its first
    occupied voxel, within ``max_range`` (map frame: ``origin`` at the grid's corner). A ray
    that misses the box costs nothing, one that leaves it stops. 3D DDA (Amanatides & Woo) that
    crosses uniform blocks (all unknown or all free, wholly in or out of the roi) in one step:
    the voxels a DDA visits in a block are 1 + the boundary crossings before it leaves.
    ``grid``: the states in blocks (``blocked``), ``shape`` the map's, ``grid_hi`` its far
    corner."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    gby, gbz = (ny + 7) >> 3, (nz + 7) >> 3
    r0, r1 = _clip(o, u, box_lo, box_hi, 0.0, max_range)
    if r0 >= r1:
        return 0
    b0x, b0y, b0z, b1x, b1y, b1z = roi[0], roi[1], roi[2], roi[3], roi[4], roi[5]
    # clip the segment [0, min(max_range, leaving the box)] to the grid's box
    t0, t1 = _clip(o, u, origin, grid_hi, 0.0, r1)
    if t0 >= t1:
        return 0
    px = o[0] - origin[0] + u[0] * (t0 + 1e-9)
    py = o[1] - origin[1] + u[1] * (t0 + 1e-9)
    pz = o[2] - origin[2] + u[2] * (t0 + 1e-9)
    inv = 1.0 / voxel
    ix = min(max(int(px * inv), 0), nx - 1)
    iy = min(max(int(py * inv), 0), ny - 1)
    iz = min(max(int(pz * inv), 0), nz - 1)
    sx, tmx, tdx = dda_axis(px, u[0], voxel, ix)
    sy, tmy, tdy = dda_axis(py, u[1], voxel, iy)
    sz, tmz, tdz = dda_axis(pz, u[2], voxel, iz)
    limit = t1 - t0
    itx, ity, itz = 1.0 / tdx, 1.0 / tdy, 1.0 / tdz
    count = 0
    t = 0.0
    block = -1
    while t <= limit:
        s = _at(grid, ix, iy, iz, gby, gbz)
        if s == OCCUPIED:
            break
        inside = b0x <= ix < b1x and b0y <= iy < b1y and b0z <= iz < b1z
        if s == UNKNOWN and inside:
            count += 1
        here = ((ix >> 3) * 4096 + (iy >> 3)) * 4096 + (iz >> 3)
        if here != block:  # entered a block: cross it in one step if it is uniform
            block = here
            for level in range(2):
                shift = 5 if level == 0 else 3
                size = 1 << shift
                if level == 0:
                    code = codes32[ix >> 5, iy >> 5, iz >> 5]
                else:
                    code = codes8[ix >> 3, iy >> 3, iz >> 3]
                if code == MIXED:
                    continue
                gx, gy, gz = (ix >> shift) << shift, (iy >> shift) << shift, (iz >> shift) << shift
                whole_in = b0x <= gx and gx + size <= b1x and b0y <= gy and gy + size <= b1y
                whole_in = whole_in and b0z <= gz and gz + size <= b1z
                whole_out = gx + size <= b0x or gx >= b1x or gy + size <= b0y or gy >= b1y
                whole_out = whole_out or gz + size <= b0z or gz >= b1z
                if not (whole_in or whole_out):
                    continue
                nxl = _steps_left(ix, sx, nx, shift)
                nyl = _steps_left(iy, sy, ny, shift)
                nzl = _steps_left(iz, sz, nz, shift)
                leave = min(tmx + nxl * tdx, tmy + nyl * tdy, tmz + nzl * tdz)
                if leave > limit:
                    continue
                kx = _crossings(tmx, itx, leave, nxl)
                ky = _crossings(tmy, ity, leave, nyl)
                kz = _crossings(tmz, itz, leave, nzl)
                if code == ALL_UNKNOWN and whole_in:
                    count += kx + ky + kz
                ix += sx * kx
                iy += sy * ky
                iz += sz * kz
                tmx += tdx * kx
                tmy += tdy * ky
                tmz += tdz * kz
                break
        # the step to the nearest boundary, branch-free (selects, not jumps: which axis comes
        # next follows no pattern a branch predictor could learn)
        cx = tmx <= tmy and tmx <= tmz
        cy = not cx and tmy <= tmz
        cz = not cx and not cy
        t = tmx if cx else (tmy if cy else tmz)
        ix = ix + sx if cx else ix
        iy = iy + sy if cy else iy
        iz = iz + sz if cz else iz
        tmx = tmx + tdx if cx else tmx
        tmy = tmy + tdy if cy else tmy
        tmz = tmz + tdz if cz else tmz
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            break
    return count


@njit(cache=True, nogil=True, parallel=True)
def _gains(grid, shape, codes8, codes32, origin, voxel, poses, dirs, max_range, lo, hi, roi, out):
    """out[v] = Σ over the rays ``dirs`` (camera frame, unit) of view ``poses[v]``; the
    (view, chunk of rays) pairs in parallel, so one view uses every core too."""
    per = 256
    chunks = (dirs.shape[0] + per - 1) // per
    partial = np.zeros(poses.shape[0] * chunks, np.int64)
    grid_hi = origin + shape * voxel
    for job in prange(poses.shape[0] * chunks):
        v, c = job // chunks, job % chunks
        R = poses[v, :3, :3]
        o = poses[v, :3, 3].copy()
        total = 0
        u = np.empty(3)
        for r in range(c * per, min(dirs.shape[0], (c + 1) * per)):
            d = dirs[r]
            u[0] = R[0, 0] * d[0] + R[0, 1] * d[1] + R[0, 2] * d[2]
            u[1] = R[1, 0] * d[0] + R[1, 1] * d[1] + R[1, 2] * d[2]
            u[2] = R[2, 0] * d[0] + R[2, 1] * d[1] + R[2, 2] * d[2]
            total += ray_gain(
                grid, shape, codes8, codes32, origin, grid_hi, voxel, o, u, max_range, lo, hi, roi
            )
        partial[job] = total
    for v in range(poses.shape[0]):
        out[v] = partial[v * chunks : (v + 1) * chunks].sum()


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
    codes: tuple[np.ndarray, np.ndarray] | None = None,
    grid: np.ndarray | None = None,
) -> np.ndarray:
    """IG(v) (Eq. 4.6) of each view ``poses[v]`` (T_world_camera) for the camera ``rays``,
    counting the unknown voxels inside ``box`` (default: the whole map), e.g. the scene's roi.
    ``codes``, ``grid``: the map's block_codes and blocked states, when the caller has them."""
    origin = np.asarray(origin, np.float64)
    states = np.ascontiguousarray(states, dtype=np.uint8)
    if box is None:
        box = (origin, origin + np.array(states.shape) * voxel)
    # the voxels the box touches, as indices and as the box snapped outwards to the grid
    i0 = np.floor((np.asarray(box[0]) - origin) / voxel + 1e-9).astype(np.int64)
    i1 = np.ceil((np.asarray(box[1]) - origin) / voxel - 1e-9).astype(np.int64)
    poses = np.ascontiguousarray(np.asarray(poses, np.float64).reshape(-1, 4, 4))
    out = np.zeros(len(poses), np.int64)
    if len(poses):
        _gains(
            blocked(states) if grid is None else grid,
            np.array(states.shape, np.int64),
            *(block_codes(states) if codes is None else codes),
            origin,
            float(voxel),
            poses,
            np.ascontiguousarray(rays, np.float64),
            float(max_range),
            origin + i0 * voxel,
            origin + i1 * voxel,
            np.concatenate([i0, i1]),
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
    states = np.ascontiguousarray(states, dtype=np.uint8)
    codes, grid = block_codes(states), blocked(states)
    coarse = information_gain(
        states, origin, voxel, poses, pixel_rays(*intrinsics, every), max_range, box, codes, grid
    )
    gains = coarse.astype(np.float64) * every
    if best_k <= 0 or not len(poses):
        return gains, np.zeros(0, int)
    best = np.argsort(-coarse, kind="stable")[: min(best_k, len(poses))]
    fine = information_gain(
        states, origin, voxel, poses[best], pixel_rays(*intrinsics, 1), max_range, box, codes, grid
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
