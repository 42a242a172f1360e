"""The occupancy map's values in 8×8×8 blocks, in the order of its bit sets (``occupancy._slot``).

Voxel (x, y, z) is at ``(((block << 6) | ((x & 7) << 3) | (y & 7)) << 3) | (z & 7)`` of a flat
int16 array, ``block = ((x >> 3) · by + (y >> 3)) · bz + (z >> 3)``: a block's 512 values are
1 KB in a row, 16 cache lines. A scan updates its voxels block by block; in a dense (x, y, z)
array a block's 64 rows of 8 values lie in 64 lines (a quarter of each used), and updating a
kitchen frame's 3.7 M voxels moved four times the memory it needed. The grid is padded to whole
blocks; padding voxels stay unknown and are never walked, counted or saved.

Everything that reads the values by position goes through here: ``dense`` and ``from_dense``
for whole grids, ``states`` and ``count`` for boxes, ``pack_known`` / ``unpack_known`` for
snapshots (in the dense order, so that a snapshot does not depend on this layout).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

UNKNOWN = np.int16(-32768)


def blocks_of(shape: tuple[int, int, int]) -> tuple[int, int, int]:
    """Blocks along each axis of a grid of ``shape``."""
    return tuple((n + 7) >> 3 for n in shape)


def empty(shape: tuple[int, int, int]) -> np.ndarray:
    """Every voxel of a grid (and its padding) unknown."""
    return np.full(math.prod(blocks_of(shape)) << 9, UNKNOWN, np.int16)


def _six(values: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """The values as (bx, by, bz, 8, 8, 8): block, then x, y, z within it (a view)."""
    return values.reshape(*blocks_of(shape), 8, 8, 8)


def dense(values: np.ndarray, shape: tuple[int, int, int]) -> np.ndarray:
    """The grid as a dense (x, y, z) array (a copy)."""
    bx, by, bz = blocks_of(shape)
    grid = _six(values, shape).transpose(0, 3, 1, 4, 2, 5).reshape(bx * 8, by * 8, bz * 8)
    nx, ny, nz = shape
    return np.ascontiguousarray(grid[:nx, :ny, :nz])


def from_dense(grid: np.ndarray, values: np.ndarray) -> None:
    """Write a dense (x, y, z) grid into ``values`` (its padding unknown)."""
    bx, by, bz = blocks_of(grid.shape)
    padded = np.full((bx * 8, by * 8, bz * 8), UNKNOWN, np.int16)
    nx, ny, nz = grid.shape
    padded[:nx, :ny, :nz] = grid
    _six(values, grid.shape)[...] = padded.reshape(bx, 8, by, 8, bz, 8).transpose(0, 2, 4, 1, 3, 5)


@njit(cache=True, nogil=True, inline="always")
def row(x, y, by, bz):
    """Where the value of (x, y, 0) is: that of (x, y, z) is ``along(row, z)``."""
    return ((((x >> 3) * by + (y >> 3)) * bz) << 9) | ((x & 7) << 6) | ((y & 7) << 3)


@njit(cache=True, nogil=True, inline="always")
def along(r, z):
    """Where the value of (x, y, z) is, ``r`` = ``row(x, y, …)``: z's block is added (the
    block number's bits overlap), its voxel in the block fills the three low bits."""
    return r + ((z >> 3) << 9) + (z & 7)


@njit(cache=True, nogil=True)
def at(x, y, z, ny, nz):
    """Where the value of (x, y, z) is, in a grid of (·, ny, nz)."""
    return along(row(x, y, (ny + 7) >> 3, (nz + 7) >> 3), z)


@njit(cache=True, nogil=True)
def count(values, ny, nz, x0, y0, z0, x1, y1, z1, thresh_milli):
    """(unknown, free, occupied) voxels of the index box [x0, x1) × [y0, y1) × [z0, z1) of a
    grid of (·, ny, nz)."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    unknown = occupied = 0
    for x in range(x0, x1):
        for y in range(y0, y1):
            r = row(x, y, by, bz)
            for b in range(z0 >> 3, (z1 + 7) >> 3):  # the row's 8 values of each block
                at = r + (b << 9)
                for z in range(max(z0, b << 3), min(z1, (b + 1) << 3)):
                    v = values[at | (z & 7)]
                    unknown += v == -32768
                    occupied += v > thresh_milli
    voxels = max(x1 - x0, 0) * max(y1 - y0, 0) * max(z1 - z0, 0)
    return unknown, voxels - unknown - occupied, occupied


@njit(cache=True, nogil=True)
def states(values, ny, nz, x0, y0, z0, thresh_milli, out):
    """``out`` (the box's shape, from (x0, y0, z0) of a grid of (·, ny, nz)): 0 unknown, 1 free,
    2 occupied (``occupancy.STATE_*``)."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    z1 = z0 + out.shape[2]
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            r = row(x0 + i, y0 + j, by, bz)
            for b in range(z0 >> 3, (z1 + 7) >> 3):
                at = r + (b << 9)
                for z in range(max(z0, b << 3), min(z1, (b + 1) << 3)):
                    v = values[at | (z & 7)]
                    out[i, j, z - z0] = (v != -32768) + (v > thresh_milli)


@njit(cache=True, nogil=True)
def pack_known(values, known, nx, ny, nz):
    """(the known-voxel mask of the dense (x, y, z) order packed 8 to a byte, first voxel in the
    high bit, as ``np.packbits``; the known voxels' values in that order): a snapshot's map
    without a temporary of the grid's size. ``known``: the known voxels' bit set (a byte per
    row of 8 in a block, ``mark_known``), read instead of the values where a row is unknown,
    as most of a map is (a sixteenth of the memory)."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    n = 0
    for w in range(known.shape[0]):
        byte = known[w]
        while byte:
            byte &= byte - np.uint8(1)
            n += 1
    bits, out = np.zeros((nx * ny * nz + 7) // 8, np.uint8), np.empty(n, values.dtype)
    n = 0
    for x in range(nx):
        for y in range(ny):
            r = row(x, y, by, bz)
            i = (x * ny + y) * nz  # the dense index of (x, y, 0)
            for b in range(bz):
                at = r + (b << 9)
                byte = known[at >> 3]
                if byte == 0:
                    continue
                for z in range(b << 3, min((b + 1) << 3, nz)):
                    if (byte >> (z & 7)) & 1:
                        bits[(i + z) >> 3] |= np.uint8(0x80 >> ((i + z) & 7))
                        out[n] = values[at | (z & 7)]
                        n += 1
    return bits, out


@njit(cache=True, nogil=True)
def unpack_known(bits, known, nx, ny, nz, values):
    """``pack_known`` undone: the ``known`` values into ``values`` where ``bits`` says."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    k = 0
    for j in range(bits.shape[0]):
        byte = bits[j]
        if byte == 0:
            continue
        for b in range(8):
            if (byte >> (7 - b)) & 1:
                i = (j << 3) | b
                xy, z = divmod(i, nz)
                x, y = divmod(xy, ny)
                values[along(row(x, y, by, bz), z)] = known[k]
                k += 1


@njit(cache=True, nogil=True, inline="always")
def all_at(values, block, by, bz, nx, ny, nz, value):
    """Every voxel of ``block`` within the grid at ``value`` (stops at the first that is not:
    most are not)."""
    x0 = (block // (by * bz)) << 3
    y0 = ((block // bz) % by) << 3
    z0 = (block % bz) << 3
    start = block << 9
    if x0 + 8 <= nx and y0 + 8 <= ny and z0 + 8 <= nz:
        for i in range(start, start + 512):
            if values[i] != value:
                return 0
        return 1
    for x in range(min(8, nx - x0)):
        for y in range(min(8, ny - y0)):
            r = start | (x << 6) | (y << 3)
            for z in range(min(8, nz - z0)):
                if values[r | z] != value:
                    return 0
    return 1


@njit(cache=True, nogil=True, parallel=True)
def saturate(values, saturated, blocks, nx, ny, nz, d_min):
    """``saturated[b]``: every voxel of block b (within the grid) is free at the clamp
    ``d_min`` (a miss leaves it as it is), for the listed ``blocks``."""
    by, bz = (ny + 7) >> 3, (nz + 7) >> 3
    for k in prange(blocks.shape[0]):
        saturated[blocks[k]] = all_at(values, blocks[k], by, bz, nx, ny, nz, d_min)


@njit(cache=True, nogil=True, parallel=True)
def mark_known(values, known):
    """The known voxels' bit set (``occupancy._slot``'s layout: a byte per row of 8, a bit per
    voxel) of the values: a restored map's."""
    for w in prange(known.shape[0]):
        byte = np.uint8(0)
        for b in range(8):
            if values[(w << 3) | b] != -32768:
                byte |= np.uint8(1 << b)
        known[w] = byte
