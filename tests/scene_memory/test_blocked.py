"""The occupancy map's values in 8×8×8 blocks against a dense (x, y, z) array and numpy: the
same values where they are, the same counts and states of any box, and snapshots packed in the
dense order (numpy's packbits), on grids that are no multiple of 8."""

from __future__ import annotations

import numpy as np
import pytest

from services.scene_memory import blocked
from services.scene_memory.blocked import UNKNOWN

SHAPES = [(1, 1, 1), (3, 5, 7), (8, 8, 8), (9, 16, 17), (20, 13, 30)]


def random_grid(shape, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    grid = np.full(shape, UNKNOWN, np.int16)
    known = rng.random(shape) < 0.3
    known.reshape(-1)[-1] = True  # the last voxel, past the last whole row of 8
    grid[known] = rng.integers(-2000, 2000, known.sum())
    return grid


@pytest.mark.parametrize("shape", SHAPES)
def test_the_values_are_where_a_dense_grid_has_them(shape):
    grid = random_grid(shape, 1)
    values = blocked.empty(shape)
    assert len(values) == np.prod(blocked.blocks_of(shape)) * 512
    blocked.from_dense(grid, values)
    assert np.array_equal(blocked.dense(values, shape), grid)
    rng = np.random.default_rng(2)
    for x, y, z in zip(*(rng.integers(0, n, 20) for n in shape), strict=True):
        assert values[blocked.at(x, y, z, *shape[1:])] == grid[x, y, z]
    # the padding stays unknown
    assert (values != UNKNOWN).sum() == (grid != UNKNOWN).sum()


@pytest.mark.parametrize("shape", SHAPES)
def test_counts_and_states_of_a_box_as_numpy_says(shape):
    grid = random_grid(shape, 3)
    values = blocked.empty(shape)
    blocked.from_dense(grid, values)
    rng = np.random.default_rng(4)
    for _ in range(10):
        a = [int(rng.integers(0, n)) for n in shape]
        b = [int(rng.integers(lo + 1, n + 1)) for lo, n in zip(a, shape, strict=True)]
        sub = grid[a[0] : b[0], a[1] : b[1], a[2] : b[2]]
        unknown, occupied = (sub == UNKNOWN).sum(), (sub > 100).sum()
        expected = (unknown, sub.size - unknown - occupied, occupied)
        assert blocked.count(values, *shape[1:], *a, *b, 100) == expected
        out = np.empty(sub.shape, np.uint8)
        blocked.states(values, *shape[1:], *a, 100, out)
        assert np.array_equal(out, np.where(sub == UNKNOWN, 0, np.where(sub > 100, 2, 1)))


@pytest.mark.parametrize("shape", SHAPES)
def test_a_snapshot_packs_the_known_voxels_in_the_dense_order_as_numpy_would(shape):
    """The compiled packing (reading the known bits, not the values, of a row of 8 unknown
    ones) against numpy's packbits and compress of the dense grid; unpacked, the same
    values."""
    grid = random_grid(shape, 5)
    values = blocked.empty(shape)
    blocked.from_dense(grid, values)
    known_bits = np.zeros(len(values) // 8, np.uint8)
    blocked.mark_known(values, known_bits)
    bits, known = blocked.pack_known(values, known_bits, *shape)
    assert np.array_equal(bits, np.packbits(grid != UNKNOWN))
    assert np.array_equal(known, grid[grid != UNKNOWN])
    back = blocked.empty(shape)
    blocked.unpack_known(bits, known, *shape, back)
    assert np.array_equal(back, values)


def test_saturated_and_known_bits_of_a_block_that_is_cut_by_the_grid():
    shape = (9, 8, 10)  # the blocks past x = 8 and z = 8 hold 1 × 8 × 2 and 1 × 8 × 8 voxels
    grid = np.full(shape, -2000, np.int16)
    grid[0, 0, 0] = -1999  # the first block is not saturated; the others are, padding aside
    values = blocked.empty(shape)
    blocked.from_dense(grid, values)
    saturated = np.zeros(np.prod(blocked.blocks_of(shape)), np.uint8)
    blocked.saturate(values, saturated, np.arange(len(saturated)), *shape, -2000)
    assert saturated.tolist() == [0, 1, 1, 1]
    known = np.zeros(len(values) // 8, np.uint8)
    blocked.mark_known(values, known)
    assert np.unpackbits(known).sum() == grid.size
