"""Planes that are faces of a box, and planes that are no surface at all: two orthogonal faces
that touch make a box only where they meet at a convex edge (``assemble_boxes``), and the
border strips of a rectangle are no plane (``_a_frame``)."""

from __future__ import annotations

import numpy as np

from services.perception.obb import plane_box
from services.perception.primitives import (
    Extracted,
    ExtractionConfig,
    _a_frame,
    assemble_boxes,
    fill,
)


def _face(origin, u, v, normal, rng) -> Extracted:
    """A densely sampled rectangle origin + s·u + t·v (s, t in [0, 1]), 2 mm of noise, its
    normal as perception orients it (towards the camera)."""
    s, t = rng.uniform(0, 1, (2, 3000))
    points = np.asarray(origin) + np.outer(s, u) + np.outer(t, v)
    points += rng.normal(0, 0.002, points.shape)
    n = np.asarray(normal, float)
    d = -float(n @ np.asarray(origin))
    return Extracted("plane", np.arange(len(points)), points, plane_box(points, n), 0, normal=n,
                     d=d)  # fmt: skip


def test_the_top_and_front_of_a_box_make_a_box():
    """A 20 cm crate seen from the front and above: its top (normal up) and its front (normal
    towards the camera at x < 0) meet at a convex edge."""
    rng = np.random.default_rng(0)
    top = _face((0, 0, 0.2), (0.2, 0, 0), (0, 0.2, 0), (0, 0, 1), rng)
    front = _face((0, 0, 0), (0, 0.2, 0), (0, 0, 0.2), (-1, 0, 0), rng)
    out = assemble_boxes([top, front], ExtractionConfig())
    assert [p.kind for p in out] == ["box"]
    assert np.allclose(np.sort(out[0].extent), [0.2, 0.2, 0.2], atol=0.01)


def test_a_shelf_board_and_the_side_panel_above_it_stay_two_planes():
    """Inside an open shelf: a board (1 m wide, 40 cm deep, normal up) and a side panel's inner
    face standing on its end (normal towards the middle, where the camera is) touch along the
    board's side, orthogonal, as long as each other along the edge: everything a box's faces
    are, but the edge is concave. Each stays a plane (without the convexity test they became
    one "box" 40 cm × 1 m × 50 cm that swallowed the board the objects stand on)."""
    rng = np.random.default_rng(1)
    board = _face((0, 0, 0.5), (0.4, 0, 0), (0, 1.0, 0), (0, 0, 1), rng)
    panel = _face((0, 1.0, 0.5), (0.4, 0, 0), (0, 0, 0.5), (0, -1, 0), rng)
    out = assemble_boxes([board, panel], ExtractionConfig())
    assert [p.kind for p in out] == ["plane", "plane"]
    assert assemble_boxes([board, panel], ExtractionConfig(box_concave=1.0))[0].kind == "box"


def test_a_table_top_and_the_wall_behind_it_stay_two_planes():
    """A table top against a wall (the wall's face towards the camera, the table in front of
    it): concave, no box."""
    rng = np.random.default_rng(2)
    top = _face((0, 0, 0.75), (0.6, 0, 0), (0, 1.2, 0), (0, 0, 1), rng)
    wall = _face((0.6, 0, 0.75), (0, 1.2, 0), (0, 0, 0.6), (-1, 0, 0), rng)
    assert [p.kind for p in assemble_boxes([top, wall], ExtractionConfig())] == ["plane", "plane"]


def test_the_border_strips_of_a_rectangle_are_no_plane():
    """An open shelf's front: its boards' and side panels' front edges, 3 cm strips joined at
    the corners around a 1 m hole, are coplanar and one cluster; their "plane" fills little of
    its rectangle (``fill``) and is refused (``_a_frame``), which a 1 m board is not."""
    rng = np.random.default_rng(3)
    strips = [
        ((0, 0, 0), (0, 1.0, 0), (0, 0, 0.03)),
        ((0, 0, 0.97), (0, 1.0, 0), (0, 0, 0.03)),
        ((0, 0, 0), (0, 0.03, 0), (0, 0, 1.0)),
        ((0, 0.97, 0), (0, 0.03, 0), (0, 0, 1.0)),
    ]
    faces = [_face(o, u, v, (-1, 0, 0), rng) for o, u, v in strips]
    points = np.concatenate([f.points for f in faces])
    n = np.array([-1.0, 0, 0])
    frame = Extracted("plane", np.arange(len(points)), points, plane_box(points, n), 0, normal=n)
    board = _face((0, 0, 0), (0, 1.0, 0), (0, 0, 0.4), (-1, 0, 0), rng)
    config = ExtractionConfig()
    assert fill(frame) < 0.2 and _a_frame(frame, config)
    assert fill(board) > 0.9 and not _a_frame(board, config)
    assert not _a_frame(frame, ExtractionConfig(frame_fill=0))
