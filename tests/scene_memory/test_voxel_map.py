"""The registration map's kernels on plain arrays: per-voxel sums equal numpy's, every voxel is
found after the table grows, the plane of a voxel is the surface's, and ICP against the map
takes a perturbed cloud of three planes back to where it belongs."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest

from services.common.poses import pose_difference
from services.scene_memory.icp import FULL, candidates, icp, residuals, smallest_eigen
from services.scene_memory.registration import RegistrationConfig
from services.scene_memory.voxel_map import VoxelMap, find, means, summarise

NO_EYE = np.full(3, np.nan)  # no camera: no check of the side a surface is seen from


def numpy_sums(points: np.ndarray, voxel: float) -> dict[tuple[int, int, int], np.ndarray]:
    """count, Σp, Σppᵀ (xx, xy, xz, yy, yz, zz) per voxel, relative to its corner."""
    ijk = np.floor(points / voxel).astype(np.int64)
    out = {}
    for key in {tuple(k) for k in ijk}:
        p = points[(ijk == key).all(axis=1)] - np.array(key) * voxel
        outer = p[:, :, None] * p[:, None, :]
        upper = outer[:, [0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]].sum(axis=0)
        out[key] = np.concatenate([[len(p)], p.sum(axis=0), upper])
    return out


def test_summarise_matches_numpy_and_skips_non_finite_points():
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.3, 0.3, (3000, 3))
    points[::97] = np.nan
    points[5, 2] = np.inf
    index, stats = summarise(points, 0.05)
    finite = points[np.isfinite(points).all(axis=1)]
    want = numpy_sums(finite, 0.05)
    assert len(index) == len(want)
    for k, row in zip(map(tuple, index), stats, strict=True):
        np.testing.assert_allclose(row[:10], want[k], rtol=1e-12, atol=1e-12)
    assert not stats[:, 10:].any()  # no camera given: no directions
    assert stats[:, 0].sum() == len(finite)
    centres = means(index, stats, 0.05)
    assert np.all(np.floor(centres / 0.05).astype(np.int64) == index)  # a mean is in its voxel


def test_the_map_grows_and_finds_every_voxel_and_survives_a_snapshot():
    """Added in 20 chunks, the table is rehashed several times; the sums are those of one
    add, and after a pickle round trip (the snapshot's state) every voxel is still found."""
    rng = np.random.default_rng(1)
    points = rng.uniform(-2.0, 2.0, (40_000, 3))
    whole = VoxelMap.of(points, 0.1)
    grown = VoxelMap(0.1)
    for chunk in np.array_split(points, 20):
        grown.add(chunk)
    assert len(grown) == len(whole) > 1000
    for m in (grown, pickle.loads(pickle.dumps(grown))):
        table, index, stats = m.table, m.index[: len(m)], m.stats[: len(m)]
        for row in rng.choice(len(m), 500, replace=False):
            ix, iy, iz = index[row]
            assert find(table, ix, iy, iz) == row
            j = find(whole.table, ix, iy, iz)
            np.testing.assert_allclose(stats[row], whole.stats[j], rtol=1e-9, atol=1e-12)
        assert find(table, 10_000, 0, 0) == -1 and find(table, -21, -21, -21) == -1
        assert np.all(m.fitted[: len(m)] == 0)  # planes are a cache, refitted after a restore


def test_smallest_eigen_matches_numpy():
    rng = np.random.default_rng(2)

    def eigen(a: np.ndarray) -> tuple[float, np.ndarray]:
        lam, x, y, z = smallest_eigen(a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2])
        return lam, np.array([x, y, z])

    for scale in (1.0, 1e-6, 1e3):
        for _ in range(200):
            a = rng.normal(size=(3, 3)) * scale
            a = a @ a.T
            values, vectors = np.linalg.eigh(a)
            lam, got = eigen(a)
            assert lam == pytest.approx(values[0], abs=1e-9 * values[-1])
            assert abs(abs(got @ vectors[:, 0]) - 1.0) < 1e-6, (a, got, vectors[:, 0])
    # a plane's scatter: two equal eigenvalues, the normal is still unique
    lam, normal = eigen(np.diag([1.0, 1.0, 1e-8]))
    assert abs(normal[2]) == pytest.approx(1.0) and lam == pytest.approx(1e-8, abs=1e-12)


def rotation(axis, degrees: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = math.radians(degrees)
    return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K


def corner(rng: np.random.Generator, n: int = 4000) -> np.ndarray:
    """Points on three mutually orthogonal 0.6 m squares (a floor and two walls), tilted."""
    u, v = rng.uniform(0, 0.6, (2, n))
    zero = np.zeros(n)
    pts = np.vstack([np.column_stack(c) for c in ((u, v, zero), (u, zero, v), (zero, u, v))])
    return pts @ rotation([1, 2, 3], 25).T + (0.3, -0.2, 0.9)


def test_planes_of_the_map_are_the_surfaces():
    """At the true pose every point of a noise-free corner lies on its voxel's plane, and
    away from the edges (where the 3×3×3 voxels of a fit see two faces) the plane's normal is
    its face's."""
    rng = np.random.default_rng(3)
    m = VoxelMap.of(corner(rng), 0.03)
    probe = np.ascontiguousarray(corner(rng, 500))
    cache = candidates(len(probe))
    matched, r, normals = residuals(probe, *m.arrays(), 1.0, np.eye(4), 0.05, cache, NO_EYE)
    assert matched.all()
    R = rotation([1, 2, 3], 25)
    local = (probe - (0.3, -0.2, 0.9)) @ R  # the corner's own frame: faces z = 0, y = 0, x = 0
    face = np.argmin(np.abs(local), axis=1)
    inside = np.sort(np.abs(local), axis=1)[:, 1] > 0.1  # ≥ 10 cm from the other faces
    assert inside.mean() > 0.5
    cosines = np.abs(np.einsum("ij,ij->i", normals, R[:, face].T))
    assert np.all(cosines[inside] > math.cos(math.radians(1.0))), np.sort(cosines[inside])[:5]
    assert np.abs(r[inside]).max() < 1e-9
    assert np.abs(r).max() < 0.015  # at the edges: a plane through both faces' points
    # a plane whose points spread more than 2 mm about it is none: the edges lose theirs
    m = VoxelMap.of(corner(rng), 0.03)
    strict, _, _ = residuals(
        probe, *m.arrays(), 0.002, np.eye(4), 0.05, candidates(len(probe)), NO_EYE
    )
    assert strict[inside].all()
    edge = np.sort(np.abs(local), axis=1)[:, 1] < 0.01
    assert edge.sum() > 20 and not strict[edge].any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_icp_takes_a_perturbed_corner_back(seed):
    """5 cm and 3° off, with 2 mm depth noise: back within 1 mm and 0.1° in one coarse-to-fine
    run (the registration's passes: 8, 3 and 1.5 cm maps)."""
    rng = np.random.default_rng(seed)
    target = corner(rng, 20_000) + rng.normal(0, 0.002, (60_000, 3))
    source = np.ascontiguousarray(corner(rng, 1500))
    T_true = np.eye(4)
    T_prior = np.eye(4)
    T_prior[:3, :3] = rotation(rng.normal(size=3), 3.0)
    shift = rng.normal(size=3)
    T_prior[:3, 3] = 0.05 * shift / np.linalg.norm(shift)
    moved = np.ascontiguousarray(source @ T_prior[:3, :3].T + T_prior[:3, 3])
    correction = np.eye(4)
    weights = np.ones(len(moved))
    for p in RegistrationConfig().passes:
        m = VoxelMap.of(target, p.map_voxel)
        correction, steps = icp(moved, *m.arrays(), p.thickness, correction, p.distance,
                                p.kernel, 30, 1e-5, weights, candidates(len(moved)), FULL,
                                NO_EYE)  # fmt: skip
        assert steps >= 1
    metres, degrees = pose_difference(T_true, correction @ T_prior)
    assert metres < 0.001 and degrees < 0.1, (metres, degrees)
