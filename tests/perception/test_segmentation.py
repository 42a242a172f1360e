"""Segmentation on the image grid: depth jumps and concave creases cut, and where faces are
flush (no jump, no crease) the colour image parts two objects; a texture does not."""

from __future__ import annotations

import numpy as np
import pytest

from services.perception.cloud import organized_cloud
from services.perception.segmentation import segment

W, H, F = 320, 240, 600.0  # a 0.64 m × 0.48 m face at 1.2 m: object-sized


def _wall(rgb: np.ndarray):
    """A flat wall 1.2 m in front of the camera filling the image (one surface, one depth)."""
    depth = np.full((H, W), 1.2, np.float32)
    return organized_cloud(depth, rgb, F, F, (W - 1) / 2, (H - 1) / 2, np.eye(4), stride=1)


def _sizes(labels: np.ndarray, n: int) -> list[int]:
    return sorted(np.bincount(labels[labels >= 0], minlength=n).tolist(), reverse=True)


def _lit(colour, rng, shade: float = 1.0) -> np.ndarray:
    """A face of one colour under smooth lighting (brighter to the right) with sensor noise."""
    ramp = np.linspace(0.8, 1.0, W)[None, :, None] * shade
    img = np.asarray(colour, float)[None, None, :] * ramp + rng.normal(0, 2, (H, W, 3))
    return np.clip(img, 0, 255)


def test_flush_faces_of_two_colours_are_two_regions():
    """A plank's front face flush with the pillar's below it: the depth is one plane, the
    colour tells them apart (the join is a straight line across the image)."""
    rng = np.random.default_rng(0)
    rgb = _lit((40, 40, 160), rng)  # blue plank
    rgb[140:] = _lit((160, 40, 40), rng)[140:]  # red pillar below
    cloud = _wall(rgb.astype(np.uint8))
    labels, n = segment(cloud, colour=None)
    assert n == 1  # depth and normals alone: one region
    labels, n = segment(cloud)
    assert n == 2
    sizes = _sizes(labels, n)
    assert sizes[0] + sizes[1] == pytest.approx(H * W, rel=0.02)
    assert sizes[1] == pytest.approx(100 * W, rel=0.05)
    # each region holds one colour
    top, bottom = labels[70, 160], labels[200, 160]
    assert top != bottom and top >= 0 and bottom >= 0
    assert np.all(labels[:135][labels[:135] >= 0] == top)
    assert np.all(labels[145:][labels[145:] >= 0] == bottom)


def test_shades_of_one_colour_are_no_edge_but_two_greys_are():
    """Chromaticity ignores shading: one colour, darker on one half (or printed in two
    shades), is one region; two neutral greys of clearly different brightness on one flat
    surface, which have no hue to tell them apart, are two."""
    rng = np.random.default_rng(1)
    for shade in (0.85, 0.45):
        rgb = _lit((40, 150, 40), rng)
        rgb[:, 160:] = _lit((40, 150, 40), rng, shade=shade)[:, 160:]
        assert segment(_wall(rgb.astype(np.uint8)))[1] == 1
    grey = _lit((200, 200, 200), rng)
    grey[:, 160:] = _lit((90, 90, 90), rng)[:, 160:]
    assert segment(_wall(grey.astype(np.uint8)))[1] == 2


def test_a_texture_stays_one_region():
    """A checker of 6-pixel cells (a printed box): its colour edges leave only small pieces."""
    rng = np.random.default_rng(2)
    cells = ((np.arange(H)[:, None] // 6 + np.arange(W)[None, :] // 6) % 2).astype(bool)
    rgb = np.where(cells[..., None], _lit((230, 220, 40), rng), _lit((20, 40, 150), rng))
    labels, n = segment(_wall(rgb.astype(np.uint8)))
    assert n == 1 and (labels >= 0).mean() > 0.95


def test_a_coarse_pattern_stays_one_region():
    """A checker of 40-pixel cells, each cell large enough to be a part: its colours come in
    many pieces interleaved with each other, which no two objects do."""
    rng = np.random.default_rng(3)
    cells = ((np.arange(H)[:, None] // 40 + np.arange(W)[None, :] // 40) % 2).astype(bool)
    rgb = np.where(cells[..., None], _lit((60, 160, 60), rng), _lit((20, 70, 20), rng))
    labels, n = segment(_wall(rgb.astype(np.uint8)))
    assert n == 1 and (labels >= 0).mean() > 0.95


@pytest.mark.parametrize("cell", [3, 40])
def test_a_patterned_box_flush_with_a_plain_one_is_two_regions(cell):
    """A checker (fine or coarse) beside a plain face on one plane: the plain colour is one
    object, the pattern, whatever its pieces, the other."""
    rng = np.random.default_rng(4)
    cells = ((np.arange(H)[:, None] // cell + np.arange(W)[None, :] // cell) % 2).astype(bool)
    rgb = np.where(cells[..., None], _lit((200, 40, 40), rng), _lit((90, 20, 20), rng))
    rgb[:, 200:] = _lit((130, 60, 200), rng)[:, 200:]  # a plain purple box beside it
    labels, n = segment(_wall(rgb.astype(np.uint8)))
    assert n == 2
    left, right = labels[:, :195], labels[:, 205:]
    assert (left == labels[120, 100]).mean() > 0.9 and (right == labels[120, 260]).mean() > 0.97
