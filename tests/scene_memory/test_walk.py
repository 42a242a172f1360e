"""One ray's walk (``occupancy._walk``, 3D DDA) against a reference: the voxels it marks are the
ones its segment crosses, clipped to the map and to max range, and never one off the segment,
on grids whose sides are not multiples of 8, for rays that start outside, graze the faces, end
on voxel corners or run parallel to the axes: the walk skips its bounds test away from the
faces, so a step past the segment would write outside the map."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.scene_memory.occupancy import _walk

HALF_DIAGONAL = math.sqrt(3) / 2 + 1e-6  # a voxel crossed by a segment has its centre this close
SHAPES = [((13, 21, 10), 0.01, (0.0, 0.0, 0.0)), ((20, 13, 30), 0.125, (-1.0, 0.5, -0.25))]


def blocks(shape) -> tuple[int, int, int]:
    return tuple((n + 7) // 8 for n in shape)


def marked(visited: np.ndarray, shape) -> set[tuple[int, int, int]]:
    """The voxels whose bits are set in a blocked bit set (``occupancy._slot``)."""
    bx, by, bz = blocks(shape)
    bits = np.unpackbits(visited, bitorder="little").reshape(bx, by, bz, 8, 8, 8)
    dense = bits.transpose(0, 3, 1, 4, 2, 5).reshape(bx * 8, by * 8, bz * 8)
    return {tuple(int(i) for i in v) for v in np.argwhere(dense)}


def clipped(origin, end, lo, hi, max_range):
    """The segment's parameters inside the map and within range, along the unit direction
    (None: outside, or through an edge or a corner, or shorter than the walk's 2 nm nudges)."""
    d = end - origin
    length = np.linalg.norm(d)
    u = d / length
    t0, t1 = 0.0, min(length, max_range)
    for a in range(3):
        if abs(u[a]) < 1e-12:
            if not lo[a] <= origin[a] < hi[a]:
                return None
            continue
        ta, tb = sorted(((lo[a] - origin[a]) / u[a], (hi[a] - origin[a]) / u[a]))
        t0, t1 = max(t0, ta), min(t1, tb)
    return (u, t0, t1, length) if t1 - t0 >= 2e-9 else None


def walk(shape, voxel, lo, origin, end, max_range=10.0, saturated=None):
    nx, ny, nz = shape
    n = math.prod(blocks(shape))
    visited = np.zeros(n * 64, np.uint8)
    sat = np.zeros(n, np.uint8) if saturated is None else saturated
    _walk(visited, np.zeros_like(visited), sat, np.zeros(n, np.uint8), nx, ny, nz,
          np.asarray(lo, np.float64), voxel, origin, end, max_range, 0)  # fmt: skip
    return marked(visited, shape)


def corridor_distance(voxels, origin, u, t0, t1, lo, voxel) -> np.ndarray:
    """Each voxel's centre's distance to the segment, in voxels."""
    c = np.asarray(sorted(voxels), np.float64).reshape(-1, 3)
    centres = lo + (c + 0.5) * voxel
    a, b = origin + u * t0, origin + u * t1
    t = np.clip((centres - a) @ (b - a) / max((b - a) @ (b - a), 1e-30), 0.0, 1.0)
    return np.linalg.norm(centres - (a + t[:, None] * (b - a)), axis=1) / voxel


def reference(origin, u, t0, t1, lo, voxel, shape, per_voxel=400) -> set[tuple[int, int, int]]:
    """The voxels of samples along the segment, ``per_voxel`` to a voxel."""
    t = np.linspace(t0, t1, max(2, int((t1 - t0) / voxel * per_voxel)))[1:-1]
    idx = np.floor((origin + t[:, None] * u - lo) / voxel).astype(np.int64)
    idx = idx[np.all((idx >= 0) & (idx < np.array(shape)), axis=1)]
    return {tuple(int(i) for i in v) for v in np.unique(idx, axis=0)}


def random_rays(rng, shape, voxel, lo, count, snap):
    """Rays between points of the map grown by a third each way; ``snap``: on voxel corners,
    edges and face centres (the worst case for the DDA's rounding), a quarter of them on the
    map's own faces."""
    n = np.array(shape, np.float64)

    def points():
        f = rng.uniform(-n / 3, n * 4 / 3, (count, 3))
        if snap:
            f = np.round(f * 2) / 2
            face = rng.random((count, 3)) < 0.25
            f[face] = np.where(rng.random((count, 3)) < 0.5, 0.0, n)[face]
        return np.asarray(lo) + f * voxel

    return points(), points()


@pytest.mark.parametrize(("shape", "voxel", "lo"), SHAPES)
@pytest.mark.parametrize("snap", [False, True])
def test_a_walk_marks_the_voxels_its_segment_crosses_and_none_off_it(shape, voxel, lo, snap):
    rng = np.random.default_rng(7)
    lo_, hi = np.asarray(lo), np.asarray(lo) + np.array(shape) * voxel
    walked = 0
    for origin, end in zip(*random_rays(rng, shape, voxel, lo, 600, snap), strict=True):
        if np.linalg.norm(end - origin) < 1e-6:
            continue
        max_range = rng.uniform(0.3, 1.5) * np.linalg.norm(hi - lo_)
        got = walk(shape, voxel, lo, origin, end, max_range)
        seg = clipped(origin, end, lo_, hi, max_range)
        if seg is None:
            assert not got
            continue
        u, t0, t1, length = seg
        walked += bool(got)
        if got:  # every marked voxel is one the segment passes through (within rounding)
            assert corridor_distance(got, origin, u, t0, t1, lo_, voxel).max() <= HALF_DIAGONAL
        if not snap:  # and every voxel it passes through is marked, but for its end's
            ref = reference(origin, u, t0, t1, lo_, voxel, shape)
            last = tuple(int(i) for i in np.floor((origin + u * t1 - lo_) / voxel))
            missing = ref - got - ({last} if t1 >= min(length, max_range) - 1e-9 else set())
            assert not missing, (origin, end, sorted(missing))
    assert walked > 150


@pytest.mark.parametrize(("shape", "voxel", "lo"), SHAPES)
def test_rays_parallel_to_axes_whose_ends_straddle_a_boundary_stay_on_their_segment(
    shape, voxel, lo
):
    """A ray along x whose y and z change by 1e-14 across a boundary of each: the DDA steps
    along x only and must not take the steps the other axes' index change would count."""
    lo_ = np.asarray(lo, np.float64)
    hi = lo_ + np.array(shape) * voxel
    for eps in (4e-15, 1e-13, -4e-15):
        y, z = lo_[1] + 5 * voxel, lo_[2] + 4 * voxel  # on boundaries of y and z
        origin = np.array([lo_[0] + 2.4 * voxel, y + eps, z + eps])
        end = np.array([hi[0] - 1.6 * voxel, y - eps, z - eps])
        got = walk(shape, voxel, lo, origin, end)
        assert got
        u, t0, t1, _ = clipped(origin, end, lo_, hi, 10.0)
        assert corridor_distance(got, origin, u, t0, t1, lo_, voxel).max() <= HALF_DIAGONAL
        # x = 2 … the one before the end's, each once, but where y and z step (|u| > 1e-12)
        xs = sorted(v[0] for v in got)
        assert set(xs) == set(range(2, shape[0] - 2))
        assert len(got) == len(xs) <= shape[0] - 4 + 2 * (abs(eps) > 1e-14)


@pytest.mark.parametrize(("shape", "voxel", "lo"), SHAPES)
def test_saturated_blocks_are_crossed_without_marking_and_the_rest_as_before(shape, voxel, lo):
    rng = np.random.default_rng(11)
    lo_, hi = np.asarray(lo), np.asarray(lo) + np.array(shape) * voxel
    bx, by, bz = blocks(shape)
    for origin, end in zip(*random_rays(rng, shape, voxel, lo, 300, False), strict=True):
        saturated = (rng.random(bx * by * bz) < 0.4).astype(np.uint8)
        got = walk(shape, voxel, lo, origin, end, saturated=saturated)
        full = walk(shape, voxel, lo, origin, end)
        in_saturated = {v for v in full if saturated[(v[0] // 8 * by + v[1] // 8) * bz + v[2] // 8]}
        assert got == full - in_saturated
        seg = clipped(origin, end, lo_, hi, 10.0)
        assert seg is not None or not got
