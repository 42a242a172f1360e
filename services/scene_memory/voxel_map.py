"""The registered cloud summarised per voxel for registration (numba): for every voxel its
point count, Σp, Σppᵀ and the sum of the unit directions its points were seen along (from the
point to the camera), in an open-addressing hash that grows with the map.

Frames are added as they are integrated (a frame's points are first summarised in a small
table of their own, which stays in cache, then merged: one probe of the big table per voxel,
not per point), so registering a frame never rebuilds anything from the cloud. Every
observation of a surface adds to its voxels' sums, so a voxel's mean is the average of all
the views of it (depth noise averages out) and its plane the fit over every point seen.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_OFFSET = 1 << 20  # voxel indices within ±2²⁰ (±21 km at 2 cm) pack into 21 bits each
_EMPTY = -1
#: the table is grown when more than this share of its slots is taken
_LOAD = 0.5
#: a voxel's sums: count, Σp (3), Σppᵀ (6), Σ of the unit vectors from each point to the
#: camera that saw it (3: zero where no camera was given)
STATS = 13


@njit(cache=True, nogil=True, inline="always")
def key(ix: int, iy: int, iz: int) -> int:
    return ((ix + _OFFSET) << 42) | ((iy + _OFFSET) << 21) | (iz + _OFFSET)


@njit(cache=True, nogil=True, inline="always")
def _home(ix: int, iy: int, iz: int, mask: int) -> int:
    """A voxel's first slot: Fibonacci hashing of its key (× 2⁶⁴/φ, int64 arithmetic), taking
    the product's high bits, which depend on all of the key's (the low ones see only z and y).
    Tables up to 2²⁴ slots. (Placing a 2×2×2 block's voxels side by side, so that neighbours
    share cache lines, measured no faster: longer probe runs ate the gain.)"""
    return ((key(ix, iy, iz) * -7046029254386353131) >> 40) & mask


def empty_table(size: int) -> np.ndarray:
    """An open-addressing table of ``size`` (a power of two) slots, each (key, row): one cache
    line holds both, where two arrays cost a lookup two misses."""
    return np.full((size, 2), _EMPTY, np.int64)


@njit(cache=True, nogil=True)
def find(table: np.ndarray, ix: int, iy: int, iz: int) -> int:
    """The voxel's row in the stats, or -1."""
    k = key(ix, iy, iz)
    mask = table.shape[0] - 1
    h = _home(ix, iy, iz, mask)
    while table[h, 0] != _EMPTY:
        if table[h, 0] == k:
            return table[h, 1]
        h = (h + 1) & mask
    return -1


@njit(cache=True, nogil=True)
def _row(table: np.ndarray, index: np.ndarray, m: int, ix, iy, iz) -> tuple:
    """The voxel's row, a new one (``m``) if it was not in the table; (row, m after)."""
    k = key(ix, iy, iz)
    mask = table.shape[0] - 1
    h = _home(ix, iy, iz, mask)
    while table[h, 0] != _EMPTY:
        if table[h, 0] == k:
            return table[h, 1], m
        h = (h + 1) & mask
    table[h, 0] = k
    table[h, 1] = m
    index[m, 0], index[m, 1], index[m, 2] = ix, iy, iz
    return m, m + 1


@njit(cache=True, nogil=True)
def summarise(
    points: np.ndarray, voxel: float, eyes: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The points' voxels (m, 3) and their sums (m, ``STATS``): count, Σp (3), Σppᵀ (xx, xy,
    xz, yy, yz, zz), each relative to its voxel's corner (float64 sums of small numbers), and
    Σ of the unit vectors from each point to where it was seen from: ``eyes`` (1, 3) one
    camera for all, (n, 3) one per point, None: not known (zeros)."""
    n = points.shape[0]
    size = 16
    while size < 2 * n:
        size *= 2
    table = np.full((size, 2), _EMPTY, np.int64)
    index = np.empty((n, 3), np.int64)
    stats = np.zeros((n, STATS))
    inv = 1.0 / voxel
    m = 0
    for i in range(n):
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])
                and math.isfinite(points[i, 2])):  # fmt: skip
            continue
        ix = math.floor(points[i, 0] * inv)
        iy = math.floor(points[i, 1] * inv)
        iz = math.floor(points[i, 2] * inv)
        s, m = _row(table, index, m, ix, iy, iz)
        x, y, z = points[i, 0] - ix * voxel, points[i, 1] - iy * voxel, points[i, 2] - iz * voxel
        row = stats[s]
        row[0] += 1.0
        row[1] += x
        row[2] += y
        row[3] += z
        row[4] += x * x
        row[5] += x * y
        row[6] += x * z
        row[7] += y * y
        row[8] += y * z
        row[9] += z * z
        if eyes is not None:
            e = 0 if eyes.shape[0] == 1 else i
            vx, vy = eyes[e, 0] - points[i, 0], eyes[e, 1] - points[i, 1]
            vz = eyes[e, 2] - points[i, 2]
            length = math.sqrt(vx * vx + vy * vy + vz * vz)
            if length > 0:
                row[10] += vx / length
                row[11] += vy / length
                row[12] += vz / length
    return index[:m].copy(), stats[:m].copy()


@njit(cache=True, nogil=True)
def means(index: np.ndarray, stats: np.ndarray, voxel: float) -> np.ndarray:
    """Each voxel's mean point (m, 3): the voxel-grid downsampling of the points."""
    m = index.shape[0]
    out = np.empty((m, 3))
    for s in range(m):
        for k in range(3):
            out[s, k] = index[s, k] * voxel + stats[s, 1 + k] / stats[s, 0]
    return out


@njit(cache=True, nogil=True)
def _merge(table, index, stats, m, new_index, new_stats) -> int:
    """Add a frame's voxel sums to the map's (the same voxel size); the map's new size."""
    for i in range(new_index.shape[0]):
        s, m = _row(table, index, m, new_index[i, 0], new_index[i, 1], new_index[i, 2])
        for k in range(STATS):
            stats[s, k] += new_stats[i, k]
    return m


@njit(cache=True, nogil=True)
def _rehash(index: np.ndarray, m: int, size: int) -> np.ndarray:
    table = np.full((size, 2), _EMPTY, np.int64)
    mask = size - 1
    for s in range(m):
        ix, iy, iz = index[s, 0], index[s, 1], index[s, 2]
        h = _home(ix, iy, iz, mask)
        while table[h, 0] != _EMPTY:
            h = (h + 1) & mask
        table[h, 0] = key(ix, iy, iz)
        table[h, 1] = s
    return table


class VoxelMap:
    """One resolution of the map for registration. ``index[:size]``, ``stats[:size]``: the
    voxels and their sums (see ``summarise``: the directions they were seen along let a frame
    from the other side of a thin body not match its far face to the near one);
    ``planes``/``fitted``: each voxel's plane (n, d), fitted lazily by ``icp`` and refitted
    once its count has grown by half."""

    def __init__(self, voxel: float) -> None:
        self.voxel = float(voxel)
        self.size = 0
        self.table = empty_table(1024)
        self.index = np.zeros((512, 3), np.int64)
        self.stats = np.zeros((512, STATS))
        self.planes = np.zeros((512, 4))
        #: the count at the last fit of the normal (0: never), negative when it failed
        self.fitted = np.zeros(512)

    @classmethod
    def of(cls, points: np.ndarray, voxel: float, eyes: np.ndarray | None = None) -> VoxelMap:
        out = cls(voxel)
        out.add(points, eyes)
        return out

    def add(self, points: np.ndarray, eyes: np.ndarray | None = None) -> None:
        """Add points (n, 3, world frame) to the sums; ``eyes``: where they were seen from
        (see ``summarise``)."""
        if eyes is not None:
            eyes = np.ascontiguousarray(np.reshape(eyes, (-1, 3)), np.float64)
        index, stats = summarise(np.ascontiguousarray(points, np.float64), self.voxel, eyes)
        need = self.size + len(index)
        if need > len(self.index):
            grow = max(need, 2 * len(self.index)) - len(self.index)
            self.index = np.concatenate([self.index, np.zeros((grow, 3), np.int64)])
            self.stats = np.concatenate([self.stats, np.zeros((grow, STATS))])
            self.planes = np.concatenate([self.planes, np.zeros((grow, 4))])
            self.fitted = np.concatenate([self.fitted, np.zeros(grow)])
        if need > _LOAD * len(self.table):
            size = len(self.table)
            while need > _LOAD * size:
                size *= 2
            self.table = _rehash(self.index, self.size, size)
        self.size = _merge(self.table, self.index, self.stats, self.size, index, stats)

    def arrays(self) -> tuple:
        """What the compiled kernels take: (table, index, stats, voxel, planes, fitted)."""
        return (self.table, self.index, self.stats, self.voxel, self.planes,
                self.fitted)  # fmt: skip

    def __len__(self) -> int:
        return self.size

    def __getstate__(self) -> dict:
        """The voxels in use and their sums only: the hash is rebuilt on load, and the planes,
        a cache, are refitted as frames meet them."""
        n = self.size
        return {"voxel": self.voxel, "index": self.index[:n], "stats": self.stats[:n]}

    def __setstate__(self, state: dict) -> None:
        self.voxel = float(state["voxel"])
        self.index = np.array(state["index"], np.int64).reshape(-1, 3)
        stats = np.array(state["stats"], np.float64).reshape(len(self.index), -1)
        if not len(self.index):
            stats = np.zeros((0, STATS))
        if stats.shape[1] < STATS:  # a snapshot from before the directions were kept
            stats = np.hstack([stats, np.zeros((len(stats), STATS - stats.shape[1]))])
        self.stats = stats
        self.size = len(self.index)
        self.planes = np.zeros((self.size, 4))
        self.fitted = np.zeros(self.size)
        size = 1024
        while self.size > _LOAD * size:
            size *= 2
        self.table = _rehash(self.index, self.size, size)
