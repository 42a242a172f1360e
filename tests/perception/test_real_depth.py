"""Perception on structured-light depth far from the camera: normals averaged over a window
that grows with z² do not see every depth step as a crease, and a "plane" as thick as it is
wide (a patch of noisy clutter) is no plane."""

from __future__ import annotations

import numpy as np

from services.perception.cloud import organized_cloud
from services.perception.obb import plane_box
from services.perception.primitives import Extracted, ExtractionConfig, _flat_enough
from services.perception.segmentation import boundaries, segment
from services.sim.noise import structured_light

W, H, F = 640, 480, 585.0  # a Kinect v1's depth camera


def _wall(z: float, seed: int = 0) -> np.ndarray:
    """A flat wall ``z`` m ahead filling the image, as a Kinect v1 measures it (σ(z) noise,
    disparity in 1/8 px steps: 18 mm steps at 2.5 m)."""
    depth = np.full((H, W), z, np.float32)
    return structured_light(depth, np.random.default_rng(seed), F)


def _cloud(depth: np.ndarray, smooth_per_m2: float):
    return organized_cloud(
        depth, None, F, F, W / 2, H / 2, np.eye(4), stride=2, smooth=3, smooth_per_m2=smooth_per_m2
    )


def test_a_wall_at_2_5_m_is_one_region_with_the_window_grown_and_crackles_without():
    depth = _wall(2.5)
    fixed, grown = _cloud(depth, 0.0), _cloud(depth, 0.45)
    assert grown.radius.min() == 3  # round(0.45 · 2.5²)
    cut_fixed = boundaries(fixed)[fixed.valid].mean()
    cut_grown = boundaries(grown)[grown.valid].mean()
    assert cut_fixed > 0.03  # measured ~0.1: the depth steps read as creases
    assert cut_grown < 0.005
    labels, _ = segment(grown, min_size=30)
    assert np.bincount(labels[labels >= 0]).max() > 0.9 * grown.valid.sum()


def test_near_the_camera_the_window_is_the_fixed_one():
    cloud = _cloud(_wall(1.2), 0.45)
    assert cloud.radius.max() == 1  # round(0.45 · 1.2²) = 1: the simulator's scenes as before


def test_a_crease_at_2_5_m_still_cuts_with_the_window_grown():
    """A room's corner 2.5 m away (a wall facing the camera, and one coming towards it on
    the right, 45° between their normals: concave) stays two regions."""
    u = np.arange(W) - W / 2
    # the right wall is the plane x + z = 2.5: along the ray x = (u/F)·z, z = 2.5 / (1 + u/F)
    row = np.where(u < 0, 2.5, 2.5 / (1 + u / F)).astype(np.float32)
    depth = structured_light(np.tile(row, (H, 1)), np.random.default_rng(1), F)
    cloud = _cloud(depth, 0.45)
    cut = boundaries(cloud)[20:220]  # (the crease's ends, where no window fits, stay open)
    crease = cut[:, W // 4 - 4 : W // 4 + 4].any(axis=1)  # the centre column, stride 2
    assert crease.mean() > 0.7  # measured 0.81: at 2.5 m the noise opens it here and there
    elsewhere = np.concatenate([cut[:, 10 : W // 4 - 12], cut[:, W // 4 + 12 : W // 2 - 10]], 1)
    assert elsewhere.mean() < 0.02  # measured 0.010 (a 3-wide window: ~0.1 on a wall)


def _patch(width: float, band: float, seed: int) -> Extracted:
    """A "plane" facing the camera 2.5 m away: ``width`` square, its points spread over
    ``band`` in depth, with a strip of a neighbouring face along one edge (as an inlier set
    grown across a crease has)."""
    rng = np.random.default_rng(seed)
    n = 400
    pts = np.column_stack(
        [rng.uniform(0, width, n), rng.uniform(0, width, n), 2.5 + rng.uniform(-band, band, n) / 2]
    )
    pts[:20, 2] = 2.5 + rng.uniform(0, 0.05, 20)  # the neighbour's strip: 5 cm deep
    normal = np.array([0.0, 0.0, -1.0])
    return Extracted("plane", np.arange(n), pts, plane_box(pts, normal), 0, normal=normal, d=2.5)


def test_a_patch_as_thick_as_it_is_wide_is_no_plane():
    config = ExtractionConfig()
    # far clutter: 8 cm across, 4 cm thick (d(z) is 2.9 cm at 2.5 m)
    assert not _flat_enough(_patch(0.08, 0.04, 0), config)
    assert _flat_enough(_patch(0.08, 0.04, 0), ExtractionConfig(flat_ratio=0.0))
    # a wall there: 0.5 m across, as thick
    assert _flat_enough(_patch(0.5, 0.04, 1), config)
    # a box's 3 cm side near the camera: mm thin, its OBB thickened by the neighbour's strip
    side = _patch(0.03, 0.004, 2)
    assert np.sort(side.box.extent)[0] > 0.025 and _flat_enough(side, config)
