"""An occupancy map with OctoMap's semantics on a dense, bounded voxel grid (thesis 4.3.1).

Log-odds per voxel: a hit adds log(p_hit / (1 − p_hit)), a pass-through adds
log(p_miss / (1 − p_miss)), the result is clamped to [logit(0.12), logit(0.97)]; a voxel is
occupied above probability 0.5, free at or below it, unknown until some ray has touched it.
Integrating a scan casts a ray from the sensor to every point (3D DDA, Amanatides & Woo):
voxels on the way are free, the end voxel is occupied, and within one scan each voxel is
updated once, with occupied winning (OctoMap's ``insertPointCloud``). Points beyond the
maximum range only clear space up to it. With ``discretize`` the end points are merged per
voxel first and one ray goes to each voxel's centre (OctoMap's ``discretize`` option); points
beyond the maximum range are merged by the voxel where their ray is cut, not by their far end's
(as OctoMap does): far walls 4-6 m away put several far voxels behind every voxel at the 3 m
cut, whose rays cross the same voxels to within one, and casting each of them was a third of a
kitchen frame's rays for 0.2 % of its free voxels.

Log-odds are stored as int16 thousandths; -32768 marks unknown. A bounded workspace fits a
dense array: 4 m × 4 m × 2 m at 1 cm is 32 M voxels, 64 MB, kept in 8×8×8 blocks of 1 KB
(``blocked``), the unit in which a scan updates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import get_thread_id, njit, prange

from services.common.dda import dda_axis
from services.scene_memory import blocked

UNKNOWN = blocked.UNKNOWN
SCALE = 1000.0  # stored value = log-odds × SCALE
STATE_UNKNOWN, STATE_FREE, STATE_OCCUPIED = 0, 1, 2


def logit(p: float) -> float:
    return math.log(p / (1 - p))


def depth_points(
    depth: np.ndarray,
    intrinsics: tuple[float, float, float, float],
    T_world_camera: np.ndarray,
    depth_min: float = 0.0,
    depth_max: float = np.inf,
    every: int = 1,
) -> np.ndarray:
    """World points (n, 3) of every ``every``-th pixel (row-major) of a depth image with a
    return in (depth_min, depth_max] (0 / NaN: none). ``intrinsics``: fx, fy, cx, cy."""
    z = np.ascontiguousarray(depth)
    if z.dtype not in (np.float32, np.float64):
        z = z.astype(np.float64)
    T = np.ascontiguousarray(T_world_camera, np.float64)
    fx, fy, cx, cy = (float(k) for k in intrinsics)
    return _depth_points(z, fx, fy, cx, cy, T, float(depth_min), float(depth_max), int(every))


@njit(cache=True, nogil=True)
def _depth_points(z, fx, fy, cx, cy, T, depth_min, depth_max, every):
    w = z.shape[1]
    flat = z.ravel()
    out = np.empty(((flat.size + every - 1) // every, 3), np.float64)
    n = 0
    for i in range(0, flat.size, every):
        d = np.float64(flat[i])
        if not (math.isfinite(d) and depth_min < d <= depth_max):
            continue
        v, u = divmod(i, w)
        x, y = (u - cx) / fx * d, (v - cy) / fy * d
        for a in range(3):
            out[n, a] = T[a, 0] * x + T[a, 1] * y + T[a, 2] * d + T[a, 3]
        n += 1
    return out[:n]


#: the cache of end voxels outside the map, and of the voxels where rays beyond range are cut
SEEN_SLOTS = 1 << 16
#: rays are cast in passes, coarse to fine: a pass per range here, whose rays are spaced about a
#: voxel apart at that range (one ray per direction cell of voxel / range), then the rest;
#: the blocks the coarse passes fill near the sensor the later rays cross in one step each
PASS_RANGES = (0.2, 0.4, 0.8, 1.6, 3.2)
#: a ray stops once it crossed this many voxels in a row that earlier rays cleared (``_walk``)
PATIENCE = 48
PATIENCE_REST = 16
#: a pass is cast in this many rounds (every SUBPASSES-th ray), each stopping on the voxels the
#: rounds before it cleared, so that where a ray stops does not depend on thread timing
SUBPASSES = 2
#: a pass of fewer than SUBPASSES × SMALL_PASS rays is one round
SMALL_PASS = 2048
#: a round of fewer rays is walked on the calling thread: the threads' wake-up would cost more
#: than half the walk. The first pass's few hundred rays are walked whole (a kitchen frame's
#: 408 rays: 115 k voxel steps, 1.2 ms on one thread): on both cores, 2-4 % off the frame
SERIAL_RAYS = 128
#: the direction cells cover the directions within atan(PASS_SPAN) of the scan's mean one
PASS_SPAN = 2.0
#: the rays are walked by at most this many threads, each marking its visits in a bit set of its
#: own (one bit per voxel and thread: 6 MB each for a 51 M-voxel kitchen map)
WALK_THREADS = 8
#: what a snapshot leaves out
SCRATCH = (
    "_visited",
    "_known_bits",
    "_hit",
    "_cleared",
    "_dirty",
    "_saturated",
    "_rays",
    "_keys",
    "_dir_cells",
    "_ray_scratch",
    "_seen",
    "_per_unit",
    "_grid_w",
    "_grid_off",
    "_grids",
    "_milli",
)


@dataclass(frozen=True)
class OccupancyConfig:
    voxel: float = 0.01
    p_hit: float = 0.7
    p_miss: float = 0.4
    clamp_min: float = 0.12
    clamp_max: float = 0.97
    threshold: float = 0.5
    max_range: float = 3.0
    discretize: bool = True
    #: a ray stops once it crossed ``PATIENCE`` voxels in a row that coarser rays of the same
    #: scan cleared (``_walk``); False: every ray is walked to the sensor (or the map's edge),
    #: as OctoMap's ``computeRayKeys`` does
    early_stop: bool = True
    #: a ray crosses a block whose voxels are all free at the clamp in one step (a miss changes
    #: none of them); False: voxel by voxel, each updated (to the clamp it is at already)
    skip_saturated: bool = True
    #: the threads that integrate a scan, at most numba's pool (and ``WALK_THREADS``);
    #: 0: the whole pool
    threads: int = 0


@njit(cache=True, nogil=True, inline="always")
def _slot(ix, iy, iz, by, bz):
    """(block, byte, bit) of a voxel in a blocked bit set: each 8×8×8 block is one 64-byte
    cache line, so a ray stays in one line for several steps, and a 1 cm map of 20 M voxels
    takes 2.5 MB, which stays in cache. (int64 arithmetic only: numba turns int64-uint64
    mixes into floats.)"""
    block = ((ix >> 3) * by + (iy >> 3)) * bz + (iz >> 3)
    return block, (block << 6) | ((ix & 7) << 3) | (iy & 7), np.uint8(1 << (iz & 7))


@njit(cache=True, nogil=True, inline="always")
def _claim(cells, grids):
    """The pass of a ray whose direction cells are ``cells`` (one per pass but the last, -1:
    outside the planes): the coarsest whose cell no ray claimed yet, claimed now, or the last
    pass. Each pass then holds about one ray per cell: the coarse passes fill the space near the
    sensor, which the rays of the later passes cross block by block."""
    last = cells.shape[0]
    if last == 0 or cells[0] < 0:
        return last
    for k in range(last):
        if grids[cells[k]] == 0:
            grids[cells[k]] = 1
            return k
    return last


@njit(cache=True, nogil=True, parallel=True)
def _cells(
    points, lo, voxel, origin, discretize, basis, per_unit, grid_off, grid_w, span, keys, cells
):  # fmt: skip
    """In parallel, the arithmetic of ``_hits`` that needs no order: the voxel of every point
    as one key (``_key``; -1: a NaN or inf coordinate), and the direction cells of its ray
    (to its voxel's centre with ``discretize``) in each pass's grid (``_claim``; ``cells[r, 0]``
    -1: the ray is more than acos(0.25) off the plane z = 1 of ``basis`` or beyond ``span``
    on it). A pass's cell is a square of 1 / ``per_unit[pass]`` on that plane."""
    inv = 1.0 / voxel
    for r in prange(points.shape[0]):
        px, py, pz = points[r, 0], points[r, 1], points[r, 2]
        if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
            keys[r] = -1
            continue
        key = _key(
            math.floor((px - lo[0]) * inv),
            math.floor((py - lo[1]) * inv),
            math.floor((pz - lo[2]) * inv),
        )
        keys[r] = key
        if discretize:
            fx, fy, fz = _centre(key)
            px, py, pz = lo[0] + fx * voxel, lo[1] + fy * voxel, lo[2] + fz * voxel
        dx, dy, dz = px - origin[0], py - origin[1], pz - origin[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        c = dx * basis[0, 0] + dy * basis[0, 1] + dz * basis[0, 2]
        u = v = -1.0
        if c > 0.25 * dist:
            u = (dx * basis[1, 0] + dy * basis[1, 1] + dz * basis[1, 2]) / c + span
            v = (dx * basis[2, 0] + dy * basis[2, 1] + dz * basis[2, 2]) / c + span
        if 0.0 <= u < 2 * span and 0.0 <= v < 2 * span:
            for k in range(per_unit.shape[0]):
                cells[r, k] = grid_off[k] + int(u * per_unit[k]) * grid_w[k] + int(v * per_unit[k])
        elif per_unit.shape[0]:
            cells[r, 0] = -1


@njit(cache=True, nogil=True, inline="always")
def _key(cx, cy, cz):
    """A voxel index (each within ±2^20, clamped) packed into one non-negative int64."""
    kx = min(max(cx, -(1 << 20)), (1 << 20) - 1) + (1 << 20)
    ky = min(max(cy, -(1 << 20)), (1 << 20) - 1) + (1 << 20)
    kz = min(max(cz, -(1 << 20)), (1 << 20) - 1) + (1 << 20)
    return (kx << 42) | (ky << 21) | kz


@njit(cache=True, nogil=True, inline="always")
def _centre(key):
    """The centre of the voxel ``key`` (``_key``), in voxels from the map's corner."""
    fx = ((key >> 42) - (1 << 20)) + 0.5
    fy = (((key >> 21) & ((1 << 21) - 1)) - (1 << 20)) + 0.5
    fz = ((key & ((1 << 21) - 1)) - (1 << 20)) + 0.5
    return fx, fy, fz


@njit(cache=True, nogil=True)
def _hits(
    visited, hit, dirty, nx, ny, nz, lo, voxel, origin, points, keys, cells, max_range,
    discretize, seen, grids, scratch, rays, starts,
):  # fmt: skip
    """First pass, one thread: set the hit and visited bits of the voxel of every return
    within range inside the map, and list the rays to cast in ``rays``, pass by pass (ray
    ``i`` of pass ``k`` at ``starts[k] + i``; ``starts`` gets the passes' bounds; see
    ``_claim``); returns their number. ``keys`` and ``cells``: the points' voxels and
    direction cells (``_cells``). With ``discretize`` every point is first moved to the
    centre of its voxel and one ray is cast per voxel (OctoMap's ``discretize``); the points
    outside the map are merged too, and those beyond range by the voxel of their cut, both
    through ``seen``, a direct-mapped cache of voxel keys, which may let a repeat through,
    never drop a new one; otherwise one ray per point. Points with a NaN or inf coordinate are
    skipped."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    inv = 1.0 / voxel
    mask = seen.shape[0] - 1
    levels = cells.shape[1] + 1
    count = np.zeros(levels, np.int64)
    level = np.empty(points.shape[0], np.int8)
    n = 0
    last = -2
    for r in range(points.shape[0]):
        key = keys[r]
        if key == -1:
            continue
        if discretize:
            if key == last:
                continue  # the previous point's voxel (neighbouring pixels): its ray is cast
            last = key
            fx, fy, fz = _centre(key)
            px, py, pz = lo[0] + fx * voxel, lo[1] + fy * voxel, lo[2] + fz * voxel
        else:
            px, py, pz = points[r, 0], points[r, 1], points[r, 2]
            fx, fy, fz = (px - lo[0]) * inv, (py - lo[1]) * inv, (pz - lo[2]) * inv
        dx, dy, dz = px - origin[0], py - origin[1], pz - origin[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        inside = 0 <= fx < nx and 0 <= fy < ny and 0 <= fz < nz
        if dist <= max_range and inside:
            block, w, bit = _slot(int(fx), int(fy), int(fz), by, bz)
            if hit[w] & bit:
                if discretize:
                    continue  # a ray to this voxel's centre is cast already
            else:
                hit[w] |= bit
                visited[w] |= bit
                dirty[block] = 1
        elif discretize:
            if dist > max_range:  # merged by the voxel where the ray is cut, not its far end
                cut = max_range / dist * inv
                key = _key(
                    math.floor((origin[0] - lo[0]) * inv + dx * cut),
                    math.floor((origin[1] - lo[1]) * inv + dy * cut),
                    math.floor((origin[2] - lo[2]) * inv + dz * cut),
                )
            slot = ((key * 0x9E3779B97F4A7C1) >> 20) & mask
            if seen[slot] == key:
                continue
            seen[slot] = key
        k = _claim(cells[r], grids)
        level[n] = k
        count[k] += 1
        scratch[n, 0], scratch[n, 1], scratch[n, 2] = px, py, pz
        n += 1
    starts[0] = 0
    for k in range(levels):
        starts[k + 1] = starts[k] + count[k]
    at = starts[:levels].copy()
    for i in range(n):
        j = at[level[i]]
        at[level[i]] = j + 1
        rays[j, 0], rays[j, 1], rays[j, 2] = scratch[i, 0], scratch[i, 1], scratch[i, 2]
    return n


@njit(cache=True, nogil=True, inline="always")
def _start(o, u, lo, n, voxel):
    """Along one axis: the ray's parameter interval inside [lo, lo + n·voxel)."""
    if abs(u) < 1e-12:
        inside = lo <= o < lo + n * voxel
        return (-1e30, 1e30) if inside else (1e30, -1e30)
    ta, tb = (lo - o) / u, (lo + n * voxel - o) / u
    return (ta, tb) if ta <= tb else (tb, ta)


@njit(cache=True, nogil=True)
def _walk(
    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, end, max_range, patience
):
    """One ray (3D DDA, Amanatides & Woo), walked from its end back to the sensor: sets the
    visited bit of every voxel on the way from the sensor to a return, or to the cut at
    ``max_range``, excluding the end's own voxel (OctoMap's ``computeRayKeys``), and stops
    early once ``patience`` voxels in a row were ``cleared`` already (0: never): the ray has
    joined space that the coarser passes (``_level``) cleared, which it would only cross
    again. ``cleared`` is the visited set as the pass began, so that where a ray stops does
    not depend on which rays of its own pass the other threads walked first.
    A ``saturated`` block (every voxel free at the clamp: a miss changes none of them) is
    crossed in one step, its voxels counted as cleared ones.
    ``visited`` is the walking thread's own bit set (``_free``): every step sets its bit
    and updates the run without a branch on whether the voxel was new or cleared, which no
    predictor learns where the coarser passes' rays left gaps (a shared set needed an atomic
    write, taken only for new voxels, behind such a branch: 14 % of a kitchen frame on one
    thread, 2-7 % on two).
    Scalars only: no array is allocated per ray."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    ox, oy, oz = origin[0], origin[1], origin[2]
    ux, uy, uz = end[0] - ox, end[1] - oy, end[2] - oz
    dist = math.sqrt(ux * ux + uy * uy + uz * uz)
    if dist < 1e-9:
        return
    ux, uy, uz = ux / dist, uy / dist, uz / dist
    length = min(dist, max_range)
    ax, bx = _start(ox, ux, lo[0], nx, voxel)
    ay, by_ = _start(oy, uy, lo[1], ny, voxel)
    az, bz_ = _start(oz, uz, lo[2], nz, voxel)
    t0 = max(0.0, ax, ay, az)
    t1 = min(length, bx, by_, bz_)
    if t1 - t0 < 2e-9:  # outside the map, or through an edge or corner of it
        return
    # the ray's end (a return, or the cut at max range) lies in the map: its voxel is not free
    end_inside = t1 >= length - 1e-9
    inv = 1.0 / voxel
    # the voxels of the clipped segment: from the one at t1 (the end's, skipped when the ray
    # ends inside the map) back to the one at t0
    px, py, pz = (
        ox - lo[0] + ux * (t0 + 1e-9),
        oy - lo[1] + uy * (t0 + 1e-9),
        oz - lo[2] + uz * (t0 + 1e-9),
    )
    qx, qy, qz = (
        ox - lo[0] + ux * (t1 - 1e-9),
        oy - lo[1] + uy * (t1 - 1e-9),
        oz - lo[2] + uz * (t1 - 1e-9),
    )
    ix = min(max(int(px * inv), 0), nx - 1)
    iy = min(max(int(py * inv), 0), ny - 1)
    iz = min(max(int(pz * inv), 0), nz - 1)
    jx = min(max(int(qx * inv), 0), nx - 1)
    jy = min(max(int(qy * inv), 0), ny - 1)
    jz = min(max(int(qz * inv), 0), nz - 1)
    # an axis the DDA does not step along (``dda_axis``) keeps the end's index: a ray parallel
    # to two axes whose ends straddle a boundary of each by 1e-15 took two steps too many
    ix = jx if abs(ux) <= 1e-12 else ix
    iy = jy if abs(uy) <= 1e-12 else iy
    iz = jz if abs(uz) <= 1e-12 else iz
    n = abs(jx - ix) + abs(jy - iy) + abs(jz - iz) + 1
    sx, tmx, tdx = dda_axis(qx, -ux, voxel, jx)
    sy, tmy, tdy = dda_axis(qy, -uy, voxel, jy)
    sz, tmz, tdz = dda_axis(qz, -uz, voxel, jz)
    # a ray whose ends' voxels are two voxels or more from the map's faces cannot leave the
    # map: rounding lets the DDA cross at most one boundary per axis past the start's voxel (the
    # one within 1e-15 of it), and its walk skips the bounds test of every step (10 % of a
    # kitchen frame); clamped ends, near a face, are walked with the test
    edge = not (
        min(ix, jx, iy, jy, iz, jz) >= 2
        and max(ix, jx) < nx - 2
        and max(iy, jy) < ny - 2
        and max(iz, jz) < nz - 2
    )
    # fmt: off
    if edge:
        _steps(True, visited, cleared, saturated, dirty, nx, ny, nz, by, bz, jx, jy, jz, sx, sy,
               sz, tmx, tmy, tmz, tdx, tdy, tdz, n, end_inside, patience)
    else:
        _steps(False, visited, cleared, saturated, dirty, nx, ny, nz, by, bz, jx, jy, jz, sx, sy,
               sz, tmx, tmy, tmz, tdx, tdy, tdz, n, end_inside, patience)
    # fmt: on


@njit(cache=True, nogil=True, inline="always")
def _steps(
    edge, visited, cleared, saturated, dirty, nx, ny, nz, by, bz, ix, iy, iz, sx, sy, sz, tmx,
    tmy, tmz, tdx, tdy, tdz, n, end_inside, patience,
):  # fmt: skip
    """The ``n`` voxels of ``_walk``'s ray from (ix, iy, iz) (the DDA's state: steps ``s``,
    parameters to the next boundary ``tm`` and per voxel ``td``), each step tested against the
    map's bounds only at the ``edge`` (a constant: the loop is compiled twice)."""
    run = 0
    k = 0
    while k < n:
        if k > 0 or not end_inside:
            block, w, bit = _slot(ix, iy, iz, by, bz)
            if saturated[block]:
                # to the block's last voxel on the ray, then the step out of it below
                bx_, by_b, bz_b = ix >> 3, iy >> 3, iz >> 3
                nxl = min((bx_ + 1) << 3, nx) - 1 - ix if sx > 0 else ix - (bx_ << 3)
                nyl = min((by_b + 1) << 3, ny) - 1 - iy if sy > 0 else iy - (by_b << 3)
                nzl = min((bz_b + 1) << 3, nz) - 1 - iz if sz > 0 else iz - (bz_b << 3)
                leave = min(tmx + nxl * tdx, tmy + nyl * tdy, tmz + nzl * tdz)
                kx = 0 if tmx >= leave else min(int((leave - tmx) / tdx) + 1, nxl)
                ky = 0 if tmy >= leave else min(int((leave - tmy) / tdy) + 1, nyl)
                kz = 0 if tmz >= leave else min(int((leave - tmz) / tdz) + 1, nzl)
                ix, iy, iz = ix + sx * kx, iy + sy * ky, iz + sz * kz
                tmx, tmy, tmz = tmx + tdx * kx, tmy + tdy * ky, tmz + tdz * kz
                k += kx + ky + kz
                run += 1 + kx + ky + kz
                if patience and run >= patience:
                    return
            else:
                visited[w] |= bit
                if dirty[block] == 0:
                    dirty[block] = 1
                run = (run + 1) * ((cleared[w] >> (iz & 7)) & 1)  # 0 on a voxel not cleared
                if run == patience and patience:
                    return
        k += 1
        # branch-free step along the axis of the nearest boundary: which axis it is follows
        # no pattern the branch predictor could learn
        cx = tmx <= tmy and tmx <= tmz
        cy = not cx and tmy <= tmz
        cz = not cx and not cy
        ix = ix + sx if cx else ix
        iy = iy + sy if cy else iy
        iz = iz + sz if cz else iz
        tmx = tmx + tdx if cx else tmx
        tmy = tmy + tdy if cy else tmy
        tmz = tmz + tdz if cz else tmz
        if edge and ((ix | iy | iz) < 0 or ix >= nx or iy >= ny or iz >= nz):
            break


@njit(cache=True, nogil=True, parallel=True)
def _unknown_on_rays(known, nx, ny, nz, lo, voxel, origin, ends, box):
    """Σ over rays of the unknown voxels inside the index box ``box`` (x0, y0, z0, x1, y1, z1)
    that each ray from ``origin`` to its end point crosses, its end's voxel included (3D DDA;
    only the part of a ray inside the box grown by a voxel is walked: a kitchen's rays cross
    metres of map outside the roi, which count nothing; rays in parallel). ``known``: the
    known voxels' bit set (``_mark_known``), 6 MB for a kitchen map where the values take 100:
    a ray's steps stay in cache."""
    blocks_y, blocks_z = (ny + 7) >> 3, (nz + 7) >> 3
    # the walked part: the box grown by one voxel (within the map), so that where the walk
    # starts never decides about a voxel of the box; each voxel is still tested against it
    gx0, gy0, gz0 = max(box[0] - 1, 0), max(box[1] - 1, 0), max(box[2] - 1, 0)
    gx1, gy1, gz1 = min(box[3] + 1, nx), min(box[4] + 1, ny), min(box[5] + 1, nz)
    total = 0
    if gx1 <= gx0 or gy1 <= gy0 or gz1 <= gz0:
        return total
    for r in prange(ends.shape[0]):
        ux, uy, uz = ends[r, 0] - origin[0], ends[r, 1] - origin[1], ends[r, 2] - origin[2]
        dist = math.sqrt(ux * ux + uy * uy + uz * uz)
        if dist < 1e-9:
            continue
        ux, uy, uz = ux / dist, uy / dist, uz / dist
        ax, bx = _start(origin[0], ux, lo[0] + gx0 * voxel, gx1 - gx0, voxel)
        ay, by = _start(origin[1], uy, lo[1] + gy0 * voxel, gy1 - gy0, voxel)
        az, bz = _start(origin[2], uz, lo[2] + gz0 * voxel, gz1 - gz0, voxel)
        t0, t1 = max(0.0, ax, ay, az), min(dist, bx, by, bz)
        if t0 > t1:
            continue
        px = origin[0] - lo[0] + ux * (t0 + 1e-9)
        py = origin[1] - lo[1] + uy * (t0 + 1e-9)
        pz = origin[2] - lo[2] + uz * (t0 + 1e-9)
        qx = origin[0] - lo[0] + ux * (t1 - 1e-9)
        qy = origin[1] - lo[1] + uy * (t1 - 1e-9)
        qz = origin[2] - lo[2] + uz * (t1 - 1e-9)
        ix, iy, iz = int(px / voxel), int(py / voxel), int(pz / voxel)
        jx, jy, jz = int(qx / voxel), int(qy / voxel), int(qz / voxel)
        sx, tmx, tdx = dda_axis(px, ux, voxel, ix)
        sy, tmy, tdy = dda_axis(py, uy, voxel, iy)
        sz, tmz, tdz = dda_axis(pz, uz, voxel, iz)
        for _ in range(abs(jx - ix) + abs(jy - iy) + abs(jz - iz) + 1):
            if not (0 <= ix < nx and 0 <= iy < ny and 0 <= iz < nz):
                break
            if box[0] <= ix < box[3] and box[1] <= iy < box[4] and box[2] <= iz < box[5]:
                _, w, bit = _slot(ix, iy, iz, blocks_y, blocks_z)
                total += not known[w] & bit
            if tmx <= tmy and tmx <= tmz:
                ix += sx
                tmx += tdx
            elif tmy <= tmz:
                iy += sy
                tmy += tdy
            else:
                iz += sz
                tmz += tdz
    return total


@njit(cache=True, nogil=True, parallel=True)
def _free(
    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, rays, max_range, chunks,
    patience,
):  # fmt: skip
    """Second pass: the rays in parallel chunks of neighbouring rays (which share voxels), each
    thread marking its visits in its own row of ``visited`` (threads × bytes)."""
    per = (rays.shape[0] + chunks - 1) // chunks
    for c in prange(chunks):
        mine = visited[get_thread_id()]
        for r in range(c * per, min(rays.shape[0], (c + 1) * per)):
            _walk(
                mine, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, rays[r],
                max_range, patience,
            )  # fmt: skip


@njit(cache=True, nogil=True)
def _free_serial(
    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, rays, max_range, patience
):
    """``_free`` on the calling thread (the first row of ``visited``)."""
    for r in range(rays.shape[0]):
        _walk(
            visited[0], cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, rays[r],
            max_range, patience,
        )  # fmt: skip


@njit(cache=True, nogil=True)
def _snapshot(visited, cleared, dirty):
    """``cleared`` = the union of the threads' ``visited`` rows in the dirty blocks (elsewhere
    all are clear)."""
    a, b = visited.view(np.int64), cleared.view(np.int64)
    for block in range(dirty.shape[0]):
        if dirty[block]:
            for j in range(block << 3, (block + 1) << 3):
                word = a[0, j]
                for t in range(1, a.shape[0]):
                    word |= a[t, j]
                b[j] = word


@njit(cache=True, nogil=True)
def _apply_block(
    V, shape, visited, hit, cleared, known_bits, saturated, block, by, bz, d_hit, d_miss, d_min,
    d_max, box, out,
):  # fmt: skip
    """Update the visited voxels of one 8×8×8 block of the values ``V`` (``blocked``: its 1 KB
    in a row), mark them known and clear their bits. In thousandths: the rounding of
    (old / 1000 + l) · 1000 is old + round(1000 · l), old being whole. ``out``: (voxels
    updated, of them unknown before and inside the index box ``box``). ``saturated[block]``
    anew (as ``blocked.saturate``): no, once an updated voxel is above the clamp ``d_min``;
    yes, when all 512 were updated to it; else as the block's voxels say."""
    nx, ny, nz = shape
    x0 = (block // (by * bz)) << 3
    y0 = ((block // bz) % by) << 3
    z0 = (block % bz) << 3
    n = known = 0
    at_min = True
    for j in range(64):
        w = (block << 6) | j
        seen = visited[0, w]
        for t in range(1, visited.shape[0]):
            seen |= visited[t, w]
        if seen == 0:
            continue
        hits = hit[w]
        known_bits[w] |= seen
        for t in range(visited.shape[0]):
            visited[t, w] = 0
        hit[w] = 0
        cleared[w] = 0
        ix = x0 | (j >> 3)
        iy = y0 | (j & 7)
        inside = box[0] <= ix < box[3] and box[1] <= iy < box[4]
        for b in range(8):
            if (seen >> b) & 1:
                iz = z0 | b
                at = (w << 3) | b
                old = np.int32(V[at])
                if old == -32768:
                    known += inside and box[2] <= iz < box[5]
                    old = 0
                value = min(max(old + (d_hit if (hits >> b) & 1 else d_miss), d_min), d_max)
                V[at] = np.int16(value)
                at_min &= value == d_min
                n += 1
    out[0], out[1] = n, known
    if not at_min:
        saturated[block] = 0
    elif n == 512:
        saturated[block] = 1
    else:
        saturated[block] = blocked.all_at(V, block, by, bz, nx, ny, nz, d_min)


@njit(cache=True, nogil=True, parallel=True)
def _apply(
    V, shape, visited, hit, cleared, known_bits, saturated, blocks, d_hit, d_miss, d_min, d_max,
    box,
):  # fmt: skip
    """Update every visited voxel of the dirty ``blocks`` once (hit: d_hit, else d_miss, in
    thousandths, clamped to [d_min, d_max]), clear its bits and tell whether its block is
    ``saturated`` now; blocks in parallel, they share no voxel. Returns (voxels updated, of
    them unknown before inside the index box ``box``: the volume the scan made known there)."""
    by, bz = (shape[1] + 7) >> 3, (shape[2] + 7) >> 3
    counts = np.zeros((blocks.shape[0], 2), np.int64)
    for k in prange(blocks.shape[0]):
        _apply_block(
            V, shape, visited, hit, cleared, known_bits, saturated, blocks[k], by, bz, d_hit,
            d_miss, d_min, d_max, box, counts[k],
        )  # fmt: skip
    return counts[:, 0].sum(), counts[:, 1].sum()


@njit(cache=True, nogil=True)
def _integrate(
    values, shape, visited, hit, cleared, known_bits, saturated, dirty, lo, voxel, origin,
    points, keys, cells, max_range, discretize, seen, grids, per_unit, grid_off, grid_w,
    scratch, rays, milli, index, threads, walk,
):  # fmt: skip
    """``OccupancyMap.integrate`` in one call (numba's pool set to ``threads``, the walking
    threads, rows of ``visited``): its serial kernels called one by one from Python took the
    GIL back a dozen times a frame, each time waiting up to the interpreter's switch interval
    while another thread of the process held it (numba's parallel regions still take it twice
    each: ``benchmarks/gil_waits.py``). ``walk``: (PATIENCE, PATIENCE_REST, SUBPASSES,
    SMALL_PASS, SERIAL_RAYS), read when called (both patiences 0: no early stop), and 1 to
    cross saturated blocks in one step (0: the walk sees no block saturated; the updates still
    mark them). Returns (rays cast, voxels updated, of them unknown before inside the index box
    ``index``)."""
    nx, ny, nz = shape
    seen[:] = -1
    grids[:] = 0
    starts = np.zeros(per_unit.shape[0] + 2, np.int64)
    _cells(
        points, lo, voxel, origin, discretize, _basis(points, origin), per_unit, grid_off,
        grid_w, PASS_SPAN, keys, cells,
    )  # fmt: skip
    n = _hits(
        visited[0], hit, dirty, nx, ny, nz, lo, voxel, origin, points, keys, cells, max_range,
        discretize, seen, grids, scratch, rays, starts,
    )  # fmt: skip
    _walk_passes(
        visited, cleared, saturated if walk[5] else np.zeros_like(saturated), dirty, nx, ny, nz,
        lo, voxel, origin, rays, starts, max_range, threads, walk,
    )  # fmt: skip
    blocks = np.flatnonzero(dirty)
    dirty[:] = 0
    count, known = _apply(
        values, shape, visited, hit, cleared, known_bits, saturated, blocks, milli[0], milli[1],
        milli[2], milli[3], index,
    )  # fmt: skip
    return n, count, known


@njit(cache=True, nogil=True)
def _walk_passes(
    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, rays, starts, max_range,
    threads, walk,
):  # fmt: skip
    """Walk the rays of every pass (``starts``: their bounds in ``rays``, ``_hits``), in
    order, each pass's in rounds (``_integrate``'s ``walk``)."""
    patience, patience_rest, subpasses, small_pass, serial_rays, _ = walk
    last = starts.shape[0] - 2
    for k in range(starts.shape[0] - 1):
        a, b = starts[k], starts[k + 1]
        if b <= a:
            continue
        # the first pass walks whole rays: nothing is cleared before it; the last one's rays
        # each run beside one cast already, a finest cell away
        p = 0 if k == 0 else patience_rest if k == last else patience
        # in rounds (every subpasses-th ray), each stopping on what the ones before it cleared;
        # a small pass at once and on this thread (no wake-ups)
        step = subpasses if p and b - a >= subpasses * small_pass else 1
        for i in range(step):
            if p:
                _snapshot(visited, cleared, dirty)
            sub = rays[a + i : b : step]
            if sub.shape[0] < serial_rays:
                _free_serial(
                    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, sub,
                    max_range, p,
                )  # fmt: skip
            else:
                chunks = max(1, min(threads * 32, sub.shape[0] // 64 + 1))
                _free(
                    visited, cleared, saturated, dirty, nx, ny, nz, lo, voxel, origin, sub,
                    max_range, chunks, p,
                )  # fmt: skip


def _walk_threads(pool: int, cap: int = 0) -> int:
    """The threads that walk the rays, of a numba pool of ``pool`` (at most ``cap``; 0: no
    cap): a row of ``_visited`` each."""
    return min(pool, WALK_THREADS, cap or pool)


@njit(cache=True, nogil=True)
def _basis(points, origin):
    """Rows: the scan's mean direction (of a sample of about 2000 of its points) and two axes
    across it."""
    step = max(1, points.shape[0] // 2000)
    mean = np.zeros(3)
    for r in range(0, points.shape[0], step):
        dx, dy, dz = points[r, 0] - origin[0], points[r, 1] - origin[1], points[r, 2] - origin[2]
        norm = math.sqrt(dx * dx + dy * dy + dz * dz)
        if math.isfinite(norm) and norm > 1e-9:
            mean[0] += dx / norm
            mean[1] += dy / norm
            mean[2] += dz / norm
    norm = math.sqrt(mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2])
    if not norm > 1e-9:
        mean[:] = (1.0, 0.0, 0.0)
        norm = 1.0
    e0 = mean / norm
    up = np.array([0.0, 0.0, 1.0]) if abs(e0[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(e0, up)
    e1 /= math.sqrt(e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2])
    out = np.empty((3, 3))
    out[0], out[1], out[2] = e0, e1, np.cross(e0, e1)
    return out


class OccupancyMap:
    """Voxels of ``config.voxel`` over the box [lo, hi)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray, config: OccupancyConfig | None = None):
        self.config = config or OccupancyConfig()
        v = self.config.voxel
        self.lo = np.asarray(lo, np.float64)
        self.shape = tuple(math.ceil(s) for s in (np.asarray(hi) - self.lo) / v - 1e-9)
        self.hi = self.lo + np.array(self.shape) * v
        self.values = blocked.empty(self.shape)  # in 8×8×8 blocks (``blocked``; ``L``: dense)
        self._scratch()
        c = self.config
        self.l_hit, self.l_miss = logit(c.p_hit), logit(c.p_miss)
        self.l_min, self.l_max = logit(c.clamp_min), logit(c.clamp_max)
        self.l_thresh = logit(c.threshold)
        self.frames = 0
        self.version = 0
        self.rays = 0  # rays the last scan cast
        self.made_known = 0  # voxels the last scan made known in its box (``integrate``)

    def _scratch(self) -> None:
        """The bit sets of one scan (visited, hit) and a dirty flag per 8×8×8 block, all zero
        between scans; the rays' buffers, the cache of the end voxels outside the map and the
        direction cells of the passes (``_level``)."""
        blocks = math.prod((n + 7) // 8 for n in self.shape)
        # a row per walking thread (``_free``)
        threads = _walk_threads(numba.get_num_threads(), self.config.threads)
        self._visited = np.zeros((threads, blocks * 64), np.uint8)
        self._known_bits = np.zeros(blocks * 64, np.uint8)  # the known voxels (``mark_known``)
        self._hit = np.zeros(blocks * 64, np.uint8)
        self._cleared = np.zeros(blocks * 64, np.uint8)
        self._dirty = np.zeros(blocks, np.uint8)
        self._saturated = np.zeros(blocks, np.uint8)
        self._rays = np.zeros((0, 3), np.float64)
        self._keys = np.zeros(0, np.int64)
        self._dir_cells = np.zeros((0, 0), np.int32)
        self._ray_scratch = np.zeros((0, 3), np.float64)
        self._seen = np.full(SEEN_SLOTS, -1, np.int64)
        v = self.config.voxel
        ranges = [r for r in PASS_RANGES if 2 * PASS_SPAN * r / v <= 2048]  # cells ≤ 4 M a pass
        # a pass's cells per unit on the plane (range / voxel: multiplied, not divided by)
        self._per_unit = np.array([r / v for r in ranges], np.float64)
        widths = [math.ceil(2 * PASS_SPAN * d) + 1 for d in self._per_unit]
        self._grid_w = np.array(widths, np.int64)
        self._grid_off = np.concatenate([[0], np.cumsum(np.square(widths))[:-1]]).astype(np.int64)
        self._grids = np.zeros(int(np.square(widths).sum()), np.uint8)
        # the updates and their bounds in stored thousandths (``_apply``)
        c = self.config
        logits = (c.p_hit, c.p_miss, c.clamp_min, c.clamp_max)
        self._milli = tuple(round(logit(p) * SCALE) for p in logits)

    #: the known voxels' mask and values are made for each snapshot: kept without a copy
    SNAPSHOT_AS_IS = frozenset({"_known", "_values"})

    def __getstate__(self) -> dict:
        """Snapshots hold the known voxels only (a bit mask and their values) and no scratch:
        a 56 M-voxel map that has seen a few views pickles to a fraction of its 112 MB."""
        state = dict(self.__dict__)
        for k in SCRATCH:
            state.pop(k)
        state["_known"], state["_values"] = blocked.pack_known(
            state.pop("values"), self._known_bits, *self.shape
        )
        return state

    def __setstate__(self, state: dict) -> None:
        bits, known = state.pop("_known"), state.pop("_values")
        self.__dict__.update(state)
        self.shape = tuple(int(n) for n in self.shape)
        self.values = blocked.empty(self.shape)
        blocked.unpack_known(bits, known, *self.shape, self.values)
        self._rebuild()

    def _rebuild(self) -> None:
        """The scratch, and what it keeps of the values: which blocks they saturate, which
        voxels are known."""
        self._scratch()
        blocks = np.arange(len(self._saturated), dtype=np.int64)
        blocked.saturate(self.values, self._saturated, blocks, *self.shape, self._milli[2])
        blocked.mark_known(self.values, self._known_bits)

    @property
    def L(self) -> np.ndarray:
        """The log-odds thousandths as a dense (x, y, z) array: a copy (tests, tools)."""
        return blocked.dense(self.values, self.shape)

    @L.setter
    def L(self, grid: np.ndarray) -> None:
        """Replace every value (a dense (x, y, z) array of the map's shape)."""
        if grid.shape != self.shape:
            raise ValueError(f"a grid of {grid.shape} for a map of {self.shape}")
        blocked.from_dense(np.asarray(grid, np.int16), self.values)
        self._rebuild()

    @property
    def voxel(self) -> float:
        return self.config.voxel

    def integrate(
        self,
        points: np.ndarray,
        origin: np.ndarray,
        max_range: float | None = None,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> int:
        """Insert one scan: rays from ``origin`` to each point (world, metres). Returns the
        number of voxels updated; ``made_known`` is then how many of them were unknown before
        inside the world box ``box`` (default: the map), counted as they are updated."""
        points = np.ascontiguousarray(np.asarray(points, np.float64).reshape(-1, 3))
        # a copy: numba compiles its kernels anew for a read-only array (a decoded pose's)
        origin = np.array(origin, np.float64)
        max_range = self.config.max_range if max_range is None else max_range
        if len(self._rays) < len(points):
            self._rays = np.empty((len(points), 3), np.float64)
            self._ray_scratch = np.empty((len(points), 3), np.float64)
        nx, ny, nz = self.shape
        pool = numba.get_num_threads()
        c = self.config
        threads = _walk_threads(pool, c.threads)
        if len(self._visited) < threads:  # more threads than when the map was made
            self._visited = np.zeros((threads, self._visited.shape[1]), np.uint8)
        if len(self._keys) < len(points):
            self._keys = np.empty(len(points), np.int64)
            self._dir_cells = np.empty((len(points), len(self._per_unit)), np.int32)
        index = np.array(self._index_box(*box) if box is not None else (0, 0, 0, nx, ny, nz),
                         np.int64)  # fmt: skip
        if pool > threads:
            numba.set_num_threads(threads)  # a thread's id must name a row of ``_visited``
        try:
            self.rays, count, known = _integrate(
                self.values, self.shape, self._visited, self._hit, self._cleared, self._known_bits,
                self._saturated, self._dirty, self.lo, self.voxel, origin, points,
                self._keys[: len(points)], self._dir_cells[: len(points)], max_range,
                self.config.discretize, self._seen, self._grids, self._per_unit, self._grid_off,
                self._grid_w, self._ray_scratch, self._rays, self._milli, index, threads,
                (PATIENCE if c.early_stop else 0, PATIENCE_REST if c.early_stop else 0,
                 SUBPASSES, SMALL_PASS, SERIAL_RAYS, int(c.skip_saturated)),
            )  # fmt: skip
        finally:
            numba.set_num_threads(pool)
        self.made_known = int(known)
        self.frames += 1
        self.version += 1
        return int(count)

    def integrate_depth(
        self,
        depth: np.ndarray,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        T_world_camera: np.ndarray,
        depth_min: float = 0.0,
        max_range: float | None = None,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> int:
        """Insert a depth image (metres along the optical axis; 0 / NaN = no return, skipped);
        ``box`` as in ``integrate``."""
        world = depth_points(depth, (fx, fy, cx, cy), T_world_camera, depth_min)
        return self.integrate(world, T_world_camera[:3, 3], max_range, box)

    def unknown_on_rays(
        self,
        depth: np.ndarray,
        intrinsics: tuple[float, float, float, float],
        T_world_camera: np.ndarray,
        box: tuple[np.ndarray, np.ndarray],
        depth_min: float = 0.0,
        max_range: float | None = None,
        every: int = 30,
    ) -> float:
        """The information gain of Eq. 4.6 a depth image realises on this map (call it before
        integrating the image): Σ over every ``every``-th pixel's ray of the unknown voxels in
        ``box`` it crosses up to its return, scaled by ``every`` (the planner's "rays"
        measure, on the rays the view really cast). ``intrinsics``: fx, fy, cx, cy."""
        max_range = self.config.max_range if max_range is None else max_range
        ends = depth_points(depth, intrinsics, T_world_camera, depth_min, max_range, every)
        index = np.array(self._index_box(*box), np.int64)
        origin = np.array(T_world_camera[:3, 3], np.float64)  # writable, as in integrate
        unknown = _unknown_on_rays(self._known_bits, *self.shape, self.lo, self.voxel, origin,
                                   ends, index)  # fmt: skip
        return float(every * unknown)

    def _index_box(self, box_min, box_max) -> tuple[int, int, int, int, int, int]:
        i0 = np.clip(np.floor((np.asarray(box_min) - self.lo) / self.voxel), 0, self.shape).astype(
            int
        )
        i1 = np.clip(np.ceil((np.asarray(box_max) - self.lo) / self.voxel), 0, self.shape).astype(
            int
        )
        return (*i0, *i1)

    def counts(self, box_min=None, box_max=None) -> tuple[int, int, int]:
        """(unknown, free, occupied) voxels in a box (default: the whole map)."""
        box_min = self.lo if box_min is None else box_min
        box_max = self.hi if box_max is None else box_max
        x0, y0, z0, x1, y1, z1 = self._index_box(box_min, box_max)
        thresh = int(self.l_thresh * SCALE)
        return blocked.count(self.values, *self.shape[1:], x0, y0, z0, x1, y1, z1, thresh)

    def states(self, box_min=None, box_max=None) -> tuple[np.ndarray, np.ndarray]:
        """(origin of the box's first voxel, uint8 states: 0 unknown, 1 free, 2 occupied)."""
        box_min = self.lo if box_min is None else box_min
        box_max = self.hi if box_max is None else box_max
        return self.states_in(self._index_box(box_min, box_max))

    def index_box(self, box_min=None, box_max=None) -> tuple[int, int, int, int, int, int]:
        """Voxel index range (x0, y0, z0, x1, y1, z1) a world box touches, clipped to the map."""
        box_min = self.lo if box_min is None else box_min
        box_max = self.hi if box_max is None else box_max
        return self._index_box(box_min, box_max)

    def states_in(self, index: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        """``states`` of a voxel index range (x0, y0, z0, x1, y1, z1)."""
        x0, y0, z0, x1, y1, z1 = index
        out = np.empty((max(x1 - x0, 0), max(y1 - y0, 0), max(z1 - z0, 0)), np.uint8)
        thresh = int(self.l_thresh * SCALE)
        blocked.states(self.values, *self.shape[1:], x0, y0, z0, thresh, out)
        return self.lo + np.array([x0, y0, z0]) * self.voxel, out

    def probability(self, point: np.ndarray) -> float | None:
        """Occupancy probability of the voxel at ``point`` (None when unknown or outside)."""
        k = np.floor((np.asarray(point) - self.lo) / self.voxel).astype(int)
        if np.any(k < 0) or np.any(k >= self.shape):
            return None
        v = self.values[blocked.at(*(int(i) for i in k), *self.shape[1:])]
        return None if v == UNKNOWN else 1 / (1 + math.exp(-v / SCALE))


def warm_up() -> None:
    """Integrate a small made-up scan once and ask the queries' kernels: loads the compiled
    kernels, or compiles them on a machine's first run (seconds), before the first real frame
    rather than with it."""
    m = OccupancyMap(np.zeros(3), np.ones(3), OccupancyConfig(voxel=0.05, max_range=2.0))
    depth = np.full((24, 32), 0.8, np.float32)
    T = np.eye(4)
    T[:3, 3] = (0.5, 0.5, 0.05)
    m.unknown_on_rays(depth, (30.0, 30.0, 15.5, 11.5), T, (m.lo, m.hi), every=4)
    m.integrate_depth(depth, 30.0, 30.0, 15.5, 11.5, T)
    m.counts()
    m.states()
    m.__setstate__(m.__getstate__())
