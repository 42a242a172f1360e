"""The shared separating-axis kernels (services/common/sat.py) against geometry that decides
the answer independently: boxes far apart, and points of one box found inside the other."""

import numpy as np
from scipy.spatial.transform import Rotation

from services.common.sat import boxes_overlap, pairs_overlap


def _boxes(n: int, rng: np.random.Generator):
    R = Rotation.random(n, random_state=rng).as_matrix()
    c = rng.uniform(-0.6, 0.6, (n, 3))
    e = rng.uniform(0.05, 0.6, (n, 3))
    return R, c, e


def _inside(points, R, c, e) -> np.ndarray:
    return np.all(np.abs((points - c) @ R) <= e / 2, axis=1)


def test_pairs_agree_with_sampled_overlap_and_distance():
    rng = np.random.default_rng(3)
    R, c, e = _boxes(40, rng)
    hit = pairs_overlap(R, c, e)
    assert hit.shape == (40, 40) and np.array_equal(hit, hit.T) and hit.diagonal().all()
    grid = np.stack(np.meshgrid(*[np.linspace(-0.5, 0.5, 9)] * 3), -1).reshape(-1, 3)
    sure_in = sure_out = 0
    for a in range(40):
        pts = c[a] + (grid * e[a]) @ R[a].T  # a 9³ lattice filling box a
        for b in range(a + 1, 40):
            assert hit[a, b] == boxes_overlap(R[a], c[a], e[a], R[b], c[b], e[b])
            if _inside(pts, R[b], c[b], e[b]).any():  # a shared point: they overlap
                assert hit[a, b]
                sure_in += 1
            radii = (np.linalg.norm(e[a]) + np.linalg.norm(e[b])) / 2
            if np.linalg.norm(c[a] - c[b]) > radii:  # farther than their spheres: apart
                assert not hit[a, b]
                sure_out += 1
    assert sure_in > 50 and sure_out > 50  # both sides of the test were exercised


def test_epsilon_grows_every_side():
    R, c, e = np.eye(3), np.zeros(3), np.ones(3)
    gap = np.array([1.04, 0.0, 0.0])  # 4 cm between two unit cubes
    assert not boxes_overlap(R, c, e, R, c + gap, e)
    assert not boxes_overlap(R, c, e, R, c + gap, e, epsilon=0.019)
    assert boxes_overlap(R, c, e, R, c + gap, e, epsilon=0.021)
    tilted = Rotation.from_euler("z", 45, degrees=True).as_matrix()
    # a cube turned 45° reaches √2/2 from its centre: 0.2 m of gap stays closed at 1.21
    assert boxes_overlap(R, c, e, tilted, np.array([1.2, 0, 0]), e)
    assert not boxes_overlap(R, c, e, tilted, np.array([1.22, 0, 0]), e)


def _separated_on(axes: np.ndarray, Ra, ca, ea, Rb, cb, eb) -> bool:
    """Some axis of ``axes`` (rows) separates the boxes' projections (numpy, the definition)."""
    n = np.linalg.norm(axes, axis=1)
    axes = axes[n > 1e-9] / n[n > 1e-9, None]
    ra = np.abs(axes @ Ra) @ (ea / 2)
    rb = np.abs(axes @ Rb) @ (eb / 2)
    return bool(np.any(np.abs(axes @ (cb - ca)) > ra + rb))


def test_edge_crossings_separate_what_the_faces_do_not():
    """Pairs that only an edge-cross axis separates (their face normals all overlap) are
    apart: the kernel agrees with the 15-axis definition on every pair, and such pairs occur."""
    rng = np.random.default_rng(11)
    R, c, e = _boxes(300, rng)
    hit = pairs_overlap(R, c, e)
    edge_only = 0
    for a in range(300):
        for b in range(a + 1, 300):
            faces = np.concatenate([R[a].T, R[b].T])
            crosses = np.cross(R[a].T[:, None, :], R[b].T[None, :, :]).reshape(9, 3)
            apart = _separated_on(
                np.concatenate([faces, crosses]), R[a], c[a], e[a], R[b], c[b], e[b]
            )
            assert hit[a, b] == (not apart), (a, b)
            edge_only += apart and not _separated_on(faces, R[a], c[a], e[a], R[b], c[b], e[b])
    assert edge_only > 0
