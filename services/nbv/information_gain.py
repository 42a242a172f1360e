"""Predicted information gain (thesis 4.3.1, Eq. 4.6): cast the camera's pixel rays from a view
through the occupancy map and count the unknown voxels each ray traverses before its first
occupied voxel, within sensor range. Hierarchical (Vasquez-Gomez et al. 2014): every 30th ray
for all candidates, then every ray for the best k.

The map arrives as voxel states (uint8: 0 unknown, 1 free, 2 occupied, the scene memory's
``memory/occupancy/slice``). ``SkipMap`` turns them, once per map and region of interest, into
what a ray needs to know about a voxel: PASS (free, or unknown outside the roi), COUNT (unknown
in the roi) or STOP (occupied), in 8³ blocks, with, per uniform block and octant of ray
directions, the size (in blocks) of the uniform cube ahead of it. One numba kernel walks the
rays (3D DDA) and crosses such a cube in one step; (view, ray chunk) pairs in parallel."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from itertools import pairwise

import numba
import numpy as np
from numba import njit, prange

from services.common.dda import dda_axis

UNKNOWN, FREE, OCCUPIED = 0, 1, 2
PASS, COUNT, STOP, MIXED = 0, 1, 2, 3  # what a voxel (or a whole block) is to a ray
#: eight voxels of a state in a word (``_block_classes``)
FREE_8, OCCUPIED_8 = np.uint64(0x0101010101010101), np.uint64(0x0202020202020202)
MAX_RADIUS = 64  # blocks (512 voxels) ahead
TOUCH = 1e-7  # m: an occluder box that only touches a view's hull does not hide the roi
#: (view, ray chunk) jobs handed out a few at a time rather than split in halves up front: on
#: a machine whose cores other processes share (the live stack), a thread that loses its core
#: no longer holds up the other at the end (same sums: each job has its own slot)
JOBS_PER_GRAB = 16


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


@njit(cache=True, nogil=True, inline="always")
def _class(s, in_roi):
    """What a voxel of state ``s`` is to a ray."""
    if s == OCCUPIED:
        return STOP
    return COUNT if s == UNKNOWN and in_roi else PASS


@njit(cache=True, nogil=True, parallel=True)
def _block_classes(states, words, roi, classes, codes):
    """Per 8×8×8 block (flat, C order over blocks): ``codes``, its class when all its voxels
    share one, else MIXED (a block of occupied voxels too; voxels past the grid's edge do not
    count), and ``classes``, its voxels' classes in 512 contiguous bytes (a ray that crosses
    the block stays in a few cache lines; in C order every step along x or y is a new line),
    written only where a ray may read them: a uniform PASS block is left as it is, zero, which
    is PASS. ``classes`` comes zeroed. One pass over the states, block by block: a whole
    block on one side of the roi's boundary is first told uniform PASS or not by OR and AND
    over ``words`` (the states eight to a word, where a row of z is whole words; else empty),
    64 of them a block (98 % of a map's blocks are free space, or unknown outside the roi),
    and only the rest is classified voxel by voxel (the two passes this replaced, classes
    then codes, took 18 of a 20 ms build on a 1 cm table-top map; this one about 6)."""
    nx, ny, nz = states.shape
    bx, by, bz = (nx + 7) >> 3, (ny + 7) >> 3, (nz + 7) >> 3
    for i in prange(bx):
        x0 = 8 * i
        x1 = min(x0 + 8, nx)
        for j in range(by):
            y0 = 8 * j
            y1 = min(y0 + 8, ny)
            for k in range(bz):
                z0 = 8 * k
                z1 = min(z0 + 8, nz)
                b = (i * by + j) * bz + k
                whole = x1 - x0 == 8 and y1 - y0 == 8 and z1 - z0 == 8
                apart = (x1 <= roi[0] or x0 >= roi[3] or y1 <= roi[1] or y0 >= roi[4]
                         or z1 <= roi[2] or z0 >= roi[5])  # fmt: skip
                within = (roi[0] <= x0 and x1 <= roi[3] and roi[1] <= y0 and y1 <= roi[4]
                          and roi[2] <= z0 and z1 <= roi[5])  # fmt: skip
                if whole and (apart or within) and words.shape[0]:
                    # eight voxels along z in a word: their states' bits OR-ed and AND-ed
                    any_bits, all_bits = np.uint64(0), ~np.uint64(0)
                    for x in range(x0, x1):
                        for y in range(y0, y1):
                            w = words[((x * ny + y) * nz + z0) >> 3]
                            any_bits |= w
                            all_bits &= w
                    if apart and not any_bits & OCCUPIED_8:  # free or unknown
                        codes[b] = PASS
                        continue
                    if within and any_bits == FREE_8 and all_bits == FREE_8:
                        codes[b] = PASS
                        continue
                # the voxels one by one
                base = b << 9
                first = _class(
                    states[x0, y0, z0],
                    roi[0] <= x0 < roi[3] and roi[1] <= y0 < roi[4] and roi[2] <= z0 < roi[5],
                )
                code = first if first != STOP else MIXED
                for x in range(x0, x1):
                    in_x = roi[0] <= x < roi[3]
                    for y in range(y0, y1):
                        in_xy = in_x and roi[1] <= y < roi[4]
                        row = base | ((x & 7) << 6) | ((y & 7) << 3)
                        for z in range(z0, z1):
                            c = _class(states[x, y, z], in_xy and roi[2] <= z < roi[5])
                            classes[row | (z & 7)] = c
                            if c != first:
                                code = MIXED
                codes[b] = code


@njit(cache=True, nogil=True, parallel=True)
def _sub_codes(classes, codes, shape):
    """Per 8³ block, the codes of its eight 4³ octants (index 4·[x ≥ 4] + 2·[y ≥ 4] + [z ≥ 4],
    flat: block · 8 + octant), as ``_block_classes``'s codes for blocks: inside a MIXED block, a ray
    crosses a uniform octant in one step (in the roi's mixed blocks about half are, mostly
    free space in front of the surfaces). A uniform block's octants have its code; a MIXED
    block at the grid's edge has MIXED octants (the voxels past the edge are no class)."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    out = np.empty(codes.shape[0] * 8, np.uint8)
    for b in prange(codes.shape[0]):
        code = codes[b]
        if code != MIXED:
            out[b * 8 : b * 8 + 8] = code
            continue
        i, j, k = b // (by * bz), (b // bz) % by, b % bz
        if 8 * i + 8 > nx or 8 * j + 8 > ny or 8 * k + 8 > nz:
            out[b * 8 : b * 8 + 8] = MIXED
            continue
        base = b << 9
        for octant in range(8):
            x0, y0, z0 = (octant >> 2) << 2, ((octant >> 1) & 1) << 2, (octant & 1) << 2
            first = classes[base | (x0 << 6) | (y0 << 3) | z0]
            differ = first == STOP
            for x in range(x0, x0 + 4):
                for y in range(y0, y0 + 4):
                    for z in range(z0, z0 + 4):
                        differ |= classes[base | (x << 6) | (y << 3) | z] != first
            out[b * 8 + octant] = MIXED if differ else first
    return out


@njit(cache=True, nogil=True, parallel=True)
def _radii(codes, bx, by, bz):
    """Per uniform block and octant of ray directions (index 4·[sx > 0] + 2·[sy > 0] +
    [sz > 0]), the largest r ≤ MAX_RADIUS such that every block of the grid from it up to r
    blocks ahead along each axis (in the octant's direction) has its class; -1 for MIXED
    blocks. One sweep per octant, from the far corner: r(b) = 1 + min of r over the 7 blocks
    ahead of b, all of b's class (the cube of r + 1 is b and their cubes of r); past the grid
    counts as anything."""
    n = bx * by * bz
    radii = np.full((8, n), -1, np.int8)
    for octant in prange(8):
        sx, sy, sz = (octant >> 2) * 2 - 1, ((octant >> 1) & 1) * 2 - 1, (octant & 1) * 2 - 1
        r = radii[octant]
        for ii in range(bx):
            i = bx - 1 - ii if sx > 0 else ii
            for jj in range(by):
                j = by - 1 - jj if sy > 0 else jj
                for kk in range(bz):
                    k = bz - 1 - kk if sz > 0 else kk
                    b = (i * by + j) * bz + k
                    if codes[b] == MIXED:
                        continue
                    least = MAX_RADIUS - 1
                    for m in range(1, 8):
                        x, y, z = i + sx * (m >> 2), j + sy * ((m >> 1) & 1), k + sz * (m & 1)
                        if x < 0 or y < 0 or z < 0 or x >= bx or y >= by or z >= bz:
                            continue
                        nb = (x * by + y) * bz + z
                        if codes[nb] != codes[b]:
                            least = -1
                            break
                        least = min(least, np.int64(r[nb]))
                    r[b] = least + 1
    return radii


@njit(cache=True, nogil=True, parallel=True)
def _occluder_boxes(classes, codes, shape, roi):
    """Per 8³ block, the index box (x0, y0, z0, x1, y1, z1, half-open) of its occupied voxels
    outside the roi (x1 = 0: none). Only MIXED blocks hold occupied voxels."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    boxes = np.zeros((codes.shape[0], 6), np.int64)
    for b in prange(codes.shape[0]):
        if codes[b] != MIXED:
            continue
        i, j, k = b // (by * bz), (b // bz) % by, b % bz
        x0, y0, z0, x1, y1, z1 = nx, ny, nz, 0, 0, 0
        for t in range(512):
            if classes[(b << 9) | t] != STOP:
                continue
            x, y, z = 8 * i + (t >> 6), 8 * j + ((t >> 3) & 7), 8 * k + (t & 7)
            if roi[0] <= x < roi[3] and roi[1] <= y < roi[4] and roi[2] <= z < roi[5]:
                continue
            x0, y0, z0 = min(x0, x), min(y0, y), min(z0, z)
            x1, y1, z1 = max(x1, x + 1), max(y1, y + 1), max(z1, z + 1)
        if x1 > 0:
            boxes[b, 0], boxes[b, 1], boxes[b, 2] = x0, y0, z0
            boxes[b, 3], boxes[b, 4], boxes[b, 5] = x1, y1, z1
    return boxes


@njit(cache=True, nogil=True)
def _meets_hull(c, lo, hi, a_lo, a_hi):
    """Whether the box [a_lo, a_hi] meets the convex hull of the point c and the box [lo, hi]:
    the hull is the union over s ∈ [0, 1] of the boxes c + s·([lo, hi] − c), so per axis two
    linear conditions on s (that box's interval reaches a_lo and a_hi), all of them on one s
    in [0, 1]. Closed boxes: a touch counts."""
    s0, s1 = 0.0, 1.0
    for a in range(3):
        # c + s·(lo − c) ≤ a_hi  and  c + s·(hi − c) ≥ a_lo
        for slope, rhs in ((lo[a] - c[a], a_hi[a] - c[a]), (c[a] - hi[a], c[a] - a_lo[a])):
            if slope > 0:
                s1 = min(s1, rhs / slope)
            elif slope < 0:
                s0 = max(s0, rhs / slope)
            elif rhs < 0:
                return False
    return s0 <= s1


@njit(cache=True, nogil=True, parallel=True)
def _clear_views(poses, lo, hi, occluders):
    """Per view: whether no occluder box (world, (n, 6)) meets the hull of its camera and the
    roi [lo, hi]. Every ray's stretch before it enters the roi lies in that hull, so a clear
    view's rays may start at the roi: what they would cross before it is free or unknown
    outside the roi, which neither stops nor counts."""
    clear = np.ones(poses.shape[0], np.bool_)
    for v in prange(poses.shape[0]):
        c = poses[v, :3, 3]
        for b in range(occluders.shape[0]):
            if _meets_hull(c, lo, hi, occluders[b, :3], occluders[b, 3:]):
                clear[v] = False
                break
    return clear


@dataclass(frozen=True)
class SkipMap:
    """What the ray caster needs of one map and roi: voxel classes in 8³ blocks, the blocks'
    codes, their 4³ octants' codes (``subcodes``) and the radii of the uniform cubes ahead of
    them (octant × block); ``roi``: voxel index box x0, y0, z0, x1, y1, z1 and ``lo``, ``hi``
    the same box in the world; ``occluders``: per block holding occupied voxels outside the
    roi, their bounding box in the world (lo, hi: (n, 6)), which a ray may meet before it
    enters the roi."""

    classes: np.ndarray
    codes: np.ndarray
    subcodes: np.ndarray
    radii: np.ndarray
    shape: np.ndarray
    origin: np.ndarray
    voxel: float
    roi: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    occluders: np.ndarray

    @classmethod
    def build(
        cls,
        states: np.ndarray,
        origin: np.ndarray,
        voxel: float,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> SkipMap:
        """``box``: the region whose unknown voxels count (default: the whole map)."""
        # one array type whatever the caller holds (numba compiles a kernel anew for a read-only
        # array, e.g. one decoded from a message, and the warm-up must have compiled this one)
        origin = np.array(origin, np.float64)
        states = np.require(states, np.uint8, ["C_CONTIGUOUS", "WRITEABLE"])
        shape = np.array(states.shape, np.int64)
        if box is None:
            box = (origin, origin + shape * voxel)
        # the voxels the box touches, as indices and as the box snapped outwards to the grid
        i0 = np.floor((np.asarray(box[0]) - origin) / voxel + 1e-9).astype(np.int64)
        i1 = np.ceil((np.asarray(box[1]) - origin) / voxel - 1e-9).astype(np.int64)
        roi = np.concatenate([i0, i1])
        blocks = (shape + 7) >> 3
        # zeroed pages from the system: only the ones the mixed blocks' classes are written to
        # are ever touched
        classes = np.zeros(int(np.prod(blocks)) * 512, np.uint8)
        codes = np.empty(int(np.prod(blocks)), np.uint8)
        # the states eight to a word, where a row of z is whole words (else none: voxel by voxel)
        words = states.reshape(-1).view(np.uint64) if shape[2] % 8 == 0 else np.zeros(0, np.uint64)
        _block_classes(states, words, roi, classes, codes)
        subcodes = _sub_codes(classes, codes, shape)
        radii = _radii(codes, *blocks)
        lo, hi = origin + i0 * voxel, origin + i1 * voxel
        boxes = _occluder_boxes(classes, codes, shape, roi)
        boxes = boxes[boxes[:, 3] > 0]
        # shrunk by TOUCH: a box that only touches the hull (the table top under the roi's
        # floor, seen from above) is met by no ray before the roi, only by rounding
        occluders = np.concatenate(
            [origin + boxes[:, :3] * voxel + TOUCH, origin + boxes[:, 3:] * voxel - TOUCH], 1
        )
        return cls(
            classes, codes, subcodes, radii, shape, origin, float(voxel), roi, lo, hi, occluders
        )


@njit(cache=True, nogil=True, inline="always")
def _steps_left(i, s, n, lo_block, hi_block):
    """Voxel steps along one axis from voxel i before leaving the blocks [lo_block, hi_block]."""
    if s > 0:
        return min((hi_block + 1) << 3, n) - 1 - i
    return i - max(lo_block << 3, 0)


@njit(cache=True, nogil=True, inline="always")
def _cube(x):
    """x³ by two multiplications (``x ** 3`` is a call to pow on the hot path)."""
    return x * x * x


@njit(cache=True, nogil=True, inline="always")
def _steps_left_4(i, s, n):
    """Voxel steps along one axis from voxel i before leaving its 4-voxel cell (an octant)."""
    if s > 0:
        return min(((i >> 2) + 1) << 2, n) - 1 - i
    return i & 3


@njit(cache=True, nogil=True, inline="always")
def _crossings(tm, inv_td, limit, cap):
    """Boundary crossings tm, tm + td, … strictly before ``limit``, at most ``cap``
    (``inv_td`` = 1 / td: a multiplication, not a division, on the hot path)."""
    if tm >= limit:
        return 0
    return min(int((limit - tm) * inv_td) + 1, cap)


@njit(cache=True, nogil=True, inline="always")
def ray_gain(
    classes, codes, subcodes, radii, shape, origin, grid_hi, voxel, o, u, max_range, lo, hi,
    volumes=True, from_roi=False,
):  # fmt: skip
    """Unknown voxels of the roi (the box [lo, hi) in the world) on one ray from ``o`` along the
    unit ``u`` before its first occupied voxel, within ``max_range`` (map frame: ``origin`` at
    the grid's corner, ``grid_hi`` its far one). A ray that misses the roi costs nothing, one
    that leaves it stops. Returns (that count, ∫ t³ over the ray's stretches through them,
    i.e. Σ of t³ at leaving minus t³ at entering: the volume measure's; 0 without
    ``volumes``, which the rays measure does not need). ``from_roi``: the ray starts where it
    enters the roi, for a view whose rays meet nothing before it (``_clear_views``). 3D DDA
    (Amanatides & Woo) that crosses the uniform cube ahead (a SkipMap radius, of the ray's
    octant) in one step: the voxels a DDA visits in it are 1 + the boundary crossings before
    it leaves; in a MIXED block, a uniform 4³ octant (``subcodes``) likewise."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    gby, gbz = (ny + 7) >> 3, (nz + 7) >> 3
    r0, r1 = _clip(o, u, lo, hi, 0.0, max_range)
    if r0 >= r1:
        return 0, 0.0
    # clip the segment [0, min(max_range, leaving the roi)] to the grid's box
    t0, t1 = _clip(o, u, origin, grid_hi, r0 if from_roi else 0.0, r1)
    if t0 >= t1:
        return 0, 0.0
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
    octant = (sx > 0) * 4 + (sy > 0) * 2 + (sz > 0)
    count, volume = 0, 0.0
    t = 0.0
    block = sub = -1
    while t <= limit:
        bx, by, bz = ix >> 3, iy >> 3, iz >> 3
        here = (bx * gby + by) * gbz + bz
        s = PASS  # the class of the voxel entered at t when it is stepped through alone
        # a uniform cube to cross at once: its code and the voxel steps left in it per axis
        code, nxl, nyl, nzl = MIXED, 0, 0, 0
        if here != block and codes[here] != MIXED:  # a uniform block: the cube ahead of it
            block = here
            code = codes[here]
            r = np.int64(radii[octant, here])
            nxl = _steps_left(ix, sx, nx, bx - r, bx + r)
            nyl = _steps_left(iy, sy, ny, by - r, by + r)
            nzl = _steps_left(iz, sz, nz, bz - r, bz + r)
        else:
            block = here
            octant_here = (here << 3) | ((ix >> 2 & 1) << 2) | ((iy >> 2 & 1) << 1) | (iz >> 2 & 1)
            if octant_here != sub and subcodes[octant_here] != MIXED:  # a uniform 4³ octant
                sub = octant_here
                code = subcodes[octant_here]
                nxl = _steps_left_4(ix, sx, nx)
                nyl = _steps_left_4(iy, sy, ny)
                nzl = _steps_left_4(iz, sz, nz)
            else:
                s = classes[(here << 9) | ((ix & 7) << 6) | ((iy & 7) << 3) | (iz & 7)]
                if s == STOP:
                    break
                count += s  # COUNT is 1, PASS 0
        if code != MIXED:
            leave = min(tmx + nxl * tdx, tmy + nyl * tdy, tmz + nzl * tdz)
            if leave > limit:  # the ray ends in the cube
                if code == COUNT:
                    count += 1 + _crossings(tmx, itx, limit, nxl)
                    count += _crossings(tmy, ity, limit, nyl) + _crossings(tmz, itz, limit, nzl)
                    if volumes:
                        volume += _cube(t0 + limit) - _cube(t0 + t)
                return count, volume
            kx = _crossings(tmx, itx, leave, nxl)
            ky = _crossings(tmy, ity, leave, nyl)
            kz = _crossings(tmz, itz, leave, nzl)
            if code == COUNT:
                count += 1 + kx + ky + kz
                if volumes:
                    volume += _cube(t0 + leave) - _cube(t0 + t)
            ix += sx * kx
            iy += sy * ky
            iz += sz * kz
            tmx += tdx * kx
            tmy += tdy * ky
            tmz += tdz * kz
        enter = t
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
        if volumes:  # a voxel stepped through alone adds its stretch when it counts
            volume += (_cube(t0 + min(t, limit)) - _cube(t0 + enter)) * s
        if ix < 0 or iy < 0 or iz < 0 or ix >= nx or iy >= ny or iz >= nz:
            break
    return count, volume


#: the rays' arithmetic may fuse multiply-adds and assume finite, non-NaN values (every value
#: here is: a component along no axis steps 1e30, not inf): 5-6 % off the coarse pass (A/B on
#: benchmarks/nbv.py's map), the gains within 2e-15 of strict IEEE order
RAY_MATH = {"nnan", "ninf", "nsz", "arcp", "contract"}


@njit(cache=True, nogil=True, parallel=True, fastmath=RAY_MATH)
def _gains(
    classes, codes, subcodes, radii, shape, origin, voxel, poses, dirs, weights, max_range, lo, hi,
    volumes, occluders,
):  # fmt: skip
    """Per view ``poses[v]``: Σ over the rays ``dirs`` (camera frame, unit) of their counts,
    and (with ``volumes``) of their ∫ t³ times the ray's weight; the (view, chunk of rays)
    pairs in parallel, so one view uses every core too. The rays of a view that no
    ``occluders`` box can hide the roi from start at the roi (``_clear_views``)."""
    clear = _clear_views(poses, lo, hi, occluders)
    per = 256
    chunks = (dirs.shape[0] + per - 1) // per
    counts = np.zeros(poses.shape[0] * chunks, np.int64)
    sums = np.zeros(poses.shape[0] * chunks)
    grid_hi = origin + shape * voxel
    for job in prange(poses.shape[0] * chunks):
        v, c = job // chunks, job % chunks
        R = poses[v, :3, :3]
        o = poses[v, :3, 3].copy()
        total, volume = 0, 0.0
        u = np.empty(3)
        for r in range(c * per, min(dirs.shape[0], (c + 1) * per)):
            d = dirs[r]
            u[0] = R[0, 0] * d[0] + R[0, 1] * d[1] + R[0, 2] * d[2]
            u[1] = R[1, 0] * d[0] + R[1, 1] * d[1] + R[1, 2] * d[2]
            u[2] = R[2, 0] * d[0] + R[2, 1] * d[1] + R[2, 2] * d[2]
            n, m3 = ray_gain(
                classes, codes, subcodes, radii, shape, origin, grid_hi, voxel, o, u, max_range,
                lo, hi, volumes, clear[v],
            )  # fmt: skip
            total += n
            volume += weights[r] * m3
        counts[job], sums[job] = total, volume
    out, vol = np.zeros(poses.shape[0], np.int64), np.zeros(poses.shape[0])
    for v in range(poses.shape[0]):
        out[v] = counts[v * chunks : (v + 1) * chunks].sum()
        vol[v] = sums[v * chunks : (v + 1) * chunks].sum()
    return out, vol


def pixel_rays(width: int, height: int, fx: float, fy: float, cx: float, cy: float, every: int = 1):
    """Unit ray directions (camera optical frame) of every ``every``-th pixel, row-major:
    every = 30 keeps 10,240 of 640×480 (the thesis's 4.3.1)."""
    v, u = np.divmod(np.arange(0, width * height, every), width)
    d = np.column_stack([(u - cx) / fx, (v - cy) / fy, np.ones(len(u))])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def solid_angles(rays: np.ndarray, fx: float, fy: float, every: int = 1) -> np.ndarray:
    """The solid angle each ray stands for: ``every`` pixels of 1 / (fx·fy) on the image plane,
    cos³ of the ray's angle to the optical axis (z) each."""
    return every * np.asarray(rays)[:, 2] ** 3 / (fx * fy)


@functools.lru_cache(maxsize=8)
def _camera_rays(intrinsics: tuple, every: int) -> tuple[np.ndarray, np.ndarray]:
    """(pixel_rays, solid_angles) of a camera, made once: every step's fine pass needs the
    307,200 of a 640×480 camera, ~20 ms to make. Shared: not to be written to (left writable
    all the same: a read-only array is another type to numba, another compiled kernel)."""
    rays = pixel_rays(*intrinsics, every)
    return rays, solid_angles(rays, intrinsics[2], intrinsics[3], every)


def information_gain(
    states: np.ndarray | None,
    origin: np.ndarray,
    voxel: float,
    poses: np.ndarray,
    rays: np.ndarray,
    max_range: float = 3.0,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    skip: SkipMap | None = None,
    solid_angle: np.ndarray | None = None,
) -> np.ndarray:
    """IG(v) (Eq. 4.6) of each view ``poses[v]`` (T_world_camera) for the camera ``rays``,
    counting the unknown voxels inside ``box`` (default: the whole map), e.g. the scene's roi.

    With ``solid_angle`` (per ray, see ``solid_angles``), the volume measure instead: each ray
    stands for the cone of its solid angle Ω, whose unknown volume along the ray's unknown
    stretches [a, b] is Ω·(b³ − a³)/3; their sum over voxel³ estimates how many unknown voxels
    the view would see, each once (Eq. 4.6 counts a voxel once per ray through it: near
    voxels many times over), on one scale whatever rays are cast.
    ``skip``: the map's SkipMap for that box, when the caller has it (then ``states``,
    ``origin``, ``voxel`` and ``box`` are not read)."""
    if skip is None:
        skip = SkipMap.build(states, origin, voxel, box)
    poses = np.ascontiguousarray(np.asarray(poses, np.float64).reshape(-1, 4, 4))
    if not len(poses):
        return np.zeros(0, np.int64 if solid_angle is None else np.float64)
    rays = np.ascontiguousarray(rays, np.float64)
    weights = np.zeros(len(rays)) if solid_angle is None else np.asarray(solid_angle, float)
    with numba.parallel_chunksize(JOBS_PER_GRAB):
        counts, volume = _gains(
            skip.classes, skip.codes, skip.subcodes, skip.radii, skip.shape, skip.origin,
            skip.voxel, poses, rays, weights / (3 * skip.voxel**3), float(max_range), skip.lo,
            skip.hi, solid_angle is not None, skip.occluders,
        )  # fmt: skip
    return counts if solid_angle is None else volume


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
    measure: str = "rays",
    coarse: Callable[[np.ndarray], np.ndarray] | None = None,
    skip: SkipMap | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(IG of every view, the indices of the best k, whose IG is then from every ray).
    ``measure``: "rays" (Eq. 4.6: the coarse IG scaled by ``every`` so that both are on one
    scale) or "volume" (see ``information_gain``). ``coarse``: who computes the every-n-th-ray
    gains of all views (e.g. shares of them on other nbv workers), same measure and scale.
    ``skip``: the map's ``SkipMap`` for ``box`` when the caller built it already."""
    if measure not in ("rays", "volume"):
        raise ValueError(f"unknown IG measure {measure!r}: rays or volume")
    if skip is None:
        skip = SkipMap.build(states, origin, voxel, box)

    def gain(views: np.ndarray, n: int) -> np.ndarray:
        rays, omega = _camera_rays(tuple(intrinsics), n)
        omega = omega if measure == "volume" else None
        g = information_gain(
            None, origin, voxel, views, rays, max_range, skip=skip, solid_angle=omega
        )
        return g.astype(np.float64) * (n if measure == "rays" else 1)

    gains = gain(poses, every) if coarse is None else np.asarray(coarse(poses), np.float64)
    if best_k <= 0 or not len(poses):
        return gains, np.zeros(0, int)
    best = np.argsort(-gains, kind="stable")[: min(best_k, len(poses))]
    gains[best] = gain(poses[best], 1)
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


__all__ = [
    "SkipMap",
    "brute_force_gain",
    "hierarchical",
    "information_gain",
    "pixel_rays",
    "ray_gain",
    "solid_angles",
]
