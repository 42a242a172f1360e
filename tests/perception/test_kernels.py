"""The compiled kernels (and other fast paths) against the numpy/scipy code they replace: the
same answers."""

from __future__ import annotations

import numpy as np
import pytest

from services.perception import primitives, ransac
from services.perception.cloud import organized_cloud
from services.perception.relations import fifth_percentile

SHAPE = (240, 320)


@pytest.mark.parametrize("seed", range(6))
def test_near_is_a_3x3_dilation_of_the_mask(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20_000))
    pixels = np.sort(rng.choice(SHAPE[0] * SHAPE[1], n, replace=False))
    if seed % 2:  # a compact blob, as a segment is
        pixels = np.unique(rng.integers(0, 3000, n) + int(rng.integers(0, 60_000)))
    mask = rng.random(len(pixels)) < rng.random()
    got = primitives._near(pixels, mask, SHAPE)
    assert got.dtype == bool and len(got) == len(pixels)
    assert (got == primitives._near_numpy(pixels, mask, SHAPE)).all()
    assert got[mask].all()  # a masked pixel is near itself


def test_near_on_the_grid_border_and_of_nothing():
    corner = np.array([0, 1, SHAPE[1], SHAPE[1] * SHAPE[0] - 1])
    got = primitives._near(corner, np.array([True, False, False, False]), SHAPE)
    assert got.tolist() == [True, True, True, False]
    assert primitives._near(corner, np.zeros(4, bool), SHAPE).sum() == 0


@pytest.mark.parametrize("arc_rad", [0.4, 1.5, 6.28])
def test_circle_fit_matches_the_numpy_fit_and_the_truth(arc_rad):
    rng = np.random.default_rng(int(arc_rad * 10))
    theta = rng.uniform(0, arc_rad, 800)
    Q = np.column_stack([0.3 + 0.04 * np.cos(theta), -0.2 + 0.04 * np.sin(theta)])
    Q += rng.normal(scale=0.0003, size=Q.shape)
    (c, r), (c_ref, r_ref) = ransac._circle_fit(Q), ransac._circle_fit_numpy(Q)
    assert np.abs(c - c_ref).max() < 1e-7 and abs(r - r_ref) < 1e-7
    assert abs(r - 0.04) < 0.003 and np.linalg.norm(c - [0.3, -0.2]) < 0.005


def test_circle_fit_of_coincident_points_falls_back_without_raising():
    c, r = ransac._circle_fit(np.ones((20, 2)))
    assert np.isfinite(c).all() and np.isfinite(r)


def test_back_projection_matches_the_pinhole_model():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 2.5, (480, 640)).astype(np.float32)
    depth[::7, ::5] = 0.0  # no return
    depth[4, 6] = np.nan
    a = np.radians(30)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = [0.5, -1.0, 1.2]
    fx, fy, cx, cy = 525.0, 520.0, 319.5, 239.5
    cloud = organized_cloud(depth, None, fx, fy, cx, cy, T)
    z = depth[::2, ::2].astype(np.float64)
    v, u = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    cam = np.stack([(2 * u - cx) / fx * z, (2 * v - cy) / fy * z, z], axis=-1)
    expected = cam @ T[:3, :3].T + T[:3, 3]
    ok = cloud.valid
    assert ok.sum() < ok.size and not ok[2, 3]  # (4, 6) is grid (2, 3): NaN, masked
    assert np.isnan(cloud.points[~ok]).all()
    assert np.abs(cloud.points[ok] - expected[ok]).max() < 1e-5


@pytest.mark.parametrize("n", [1, 2, 3, 20, 21, 400, 1999])
def test_fifth_percentile_is_numpys(n):
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n), np.round(rng.normal(size=n), 1)):
        assert fifth_percentile(x) == pytest.approx(float(np.percentile(x, 5)), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_grid_labels_number_components_as_scipy_does(seed):
    from scipy import ndimage

    from services.perception import kernels

    rng = np.random.default_rng(seed)
    pixels = np.sort(rng.choice(SHAPE[0] * SHAPE[1], int(rng.integers(1, 30_000)), replace=False))
    if seed % 2:  # in no particular order
        rng.shuffle(pixels)
    own, n = kernels.grid_labels(pixels, SHAPE[1])
    rows, cols = np.divmod(pixels, SHAPE[1])
    grid = np.zeros((rows.max() - rows.min() + 1, cols.max() - cols.min() + 1), bool)
    grid[rows - rows.min(), cols - cols.min()] = True
    labels, n_ref = ndimage.label(grid, structure=np.ones((3, 3), bool))
    assert n == n_ref > 1
    assert (own == labels[rows - rows.min(), cols - cols.min()]).all()
