"""Level-surface outlines (``outline.py``): the outline of a table top with boxes on it lies on
the top's and the boxes' edges, and aligning a copy moved 3 cm and 2° in the ground plane
brings it back within 2 mm and 0.1°; a copy at another height is not matched to it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.common.poses import pose_difference
from services.scene_memory.outline import OutlineConfig, level_points, outline, refine


def rectangle(cx: float, cy: float, hx: float, hy: float, z: float, step: float = 0.005):
    u, v = np.meshgrid(np.arange(cx - hx, cx + hx, step), np.arange(cy - hy, cy + hy, step))
    return np.column_stack([u.ravel(), v.ravel(), np.full(u.size, z)])


def table() -> np.ndarray:
    """A 1.2 × 0.8 m top at 0.75 m, two boxes' tops on it, the floor around it."""
    top = rectangle(0.0, 0.0, 0.6, 0.4, 0.75)
    inside = lambda p, x, y, hx, hy: (np.abs(p[:, 0] - x) < hx) & (np.abs(p[:, 1] - y) < hy)  # noqa: E731
    top = top[~inside(top, 0.2, 0.1, 0.08, 0.05) & ~inside(top, -0.25, -0.15, 0.05, 0.1)]
    boxes = np.vstack(
        [rectangle(0.2, 0.1, 0.08, 0.05, 0.85), rectangle(-0.25, -0.15, 0.05, 0.1, 0.9)]
    )
    floor = rectangle(0.0, 0.0, 1.5, 1.5, 0.0, 0.02)
    rng = np.random.default_rng(0)
    cloud = np.vstack([top, boxes, floor])
    return cloud + rng.normal(0.0, 0.002, cloud.shape)


def planar(degrees: float, x: float, y: float) -> np.ndarray:
    a = math.radians(degrees)
    T = np.eye(4)
    T[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    T[:2, 3] = (x, y)
    return T


def test_the_outline_lies_on_the_edges_of_the_level_surfaces():
    cloud = table()
    level = level_points(cloud, OutlineConfig())
    assert level[:, 2].min() > 0.7  # the floor is no level surface above it
    edge = outline(cloud)

    # every outline point is within 3 cm of an edge of the top or of a box
    def to_edge(p, cx, cy, hx, hy):
        return np.minimum(np.abs(np.abs(p[:, 0] - cx) - hx), np.abs(np.abs(p[:, 1] - cy) - hy))

    d = np.minimum.reduce([
        to_edge(edge, 0.0, 0.0, 0.6, 0.4), to_edge(edge, 0.2, 0.1, 0.08, 0.05),
        to_edge(edge, -0.25, -0.15, 0.05, 0.1),
    ])  # fmt: skip
    assert len(edge) > 200 and np.percentile(d, 95) < 0.03
    assert len(edge) < 0.3 * len(level)  # the outline, not the surface


@pytest.mark.parametrize(
    "degrees, x, y", [(2.0, 0.03, 0.0), (-2.0, -0.02, 0.02), (1.0, 0.0, -0.03)]
)
def test_a_moved_outline_is_brought_back(degrees, x, y):
    cloud = table()
    moved = planar(degrees, x, y)
    frame = cloud @ moved[:3, :3].T + moved[:3, 3]
    C, weight = refine(outline(frame), outline(cloud))
    assert weight > 60
    back = C @ moved  # the frame's pose error after the correction
    metres, turn = pose_difference(np.eye(4), back)
    assert metres < 0.002 and turn < 0.1, (metres, turn)


def test_an_outline_at_another_height_is_not_matched():
    cloud = table()
    lifted = cloud + np.array([0.0, 0.0, 0.3])  # the same shapes 30 cm higher
    C, weight = refine(outline(lifted), outline(cloud))
    assert weight == 0.0 and np.array_equal(C, np.eye(4))
