"""Stability in a room: a wall whose foot is out of sight is structure, not a hint of missing
data; a flat thing against it (a poster, a shelf board) is held by it; an object beside it
still needs support from below."""

from __future__ import annotations

import numpy as np

from services.scene_memory.fusion import Fusion, FusionConfig
from tests.scene_memory.builders import box, observation, plane
from tests.scene_memory.test_evidence import facing_wall, wall


def _unstable_kinds(fusion: Fusion) -> dict[str, list[str]]:
    fusion_model = fusion.scene_model()
    out: dict[str, list[str]] = {}
    for p in fusion_model.primitives:
        key = f"{p.model.kind}@{p.obb.center[2]:.2f}"
        out.setdefault("unstable" if p.id in fusion_model.unstable_ids else "stable", []).append(
            key
        )
    return out


def test_a_wall_and_what_hangs_on_it_are_stable_an_object_beside_it_is_not():
    T = facing_wall(2.0)
    table = plane(0, (1.6, 2.6), (-0.5, 0.5), 0.72)  # the ground of the scene (ρ)
    room = wall(1, (-1.0, 1.0), 3.0, (0.9, 2.0))  # its foot hidden behind a counter
    poster = wall(2, (-0.3, 0.1), 2.99, (1.3, 1.7))  # 1 cm in front of it
    shelf = plane(3, (2.75, 2.99), (0.2, 0.8), 1.2)  # a board against it
    floating = box(4, (2.9, -0.6, 1.5), (0.1, 0.1, 0.1))  # touches the wall, nothing below
    small = wall(5, (-0.9, -0.7), 2.5, (1.0, 1.2))  # a 0.2 m panel in mid-air
    fusion = Fusion()
    fusion.update(observation(0, [table, room, poster, shelf, floating, small], T=T))
    assert len(fusion.prims) == 6
    state = _unstable_kinds(fusion)
    assert sorted(state["unstable"]) == ["box@1.50", "plane@1.10"], state
    # without structure (the thesis's rule: a chain of support edges down to ρ): the wall,
    # its poster and its board are unstable too
    strict = Fusion(FusionConfig(structure_height=np.inf, below_views=0))
    strict.update(observation(0, [table, room, poster, shelf, floating, small], T=T))
    assert len(_unstable_kinds(strict)["unstable"]) == 5
    # ... but the wall's foot and what is under the poster were never seen: their support is
    # unresolved; under the board, the box and the panel the view saw the wall behind
    seen = Fusion(FusionConfig(structure_height=np.inf))
    seen.update(observation(0, [table, room, poster, shelf, floating, small], T=T))
    state = _unstable_kinds(seen)
    assert sorted(state["unstable"]) == ["box@1.50", "plane@1.10", "plane@1.20"], state
    assert len(seen.scene_model().unresolved_ids) == 2


def test_an_object_whose_bottom_lies_on_a_stable_top_rests_without_a_seen_edge():
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    on = box(1, (0.9, 0.0, 0.77), (0.08, 0.08, 0.1))  # bottom at 0.72: on the table
    above = box(2, (0.5, 0.3, 0.87), (0.08, 0.08, 0.1))  # bottom at 0.82: 10 cm over it
    beside = box(3, (1.8, 0.0, 0.77), (0.08, 0.08, 0.1))  # at the height, off its edge
    fusion = Fusion()
    fusion.update(observation(0, [table, on, above, beside]))  # no support edges observed
    model = fusion.scene_model()
    z = {p.id: f"{p.obb.center[2]:.2f}" for p in model.primitives}
    # beside, above; straight down no view sees under a box: their support is unresolved
    assert sorted(z[i] for i in model.unstable_ids + model.unresolved_ids) == ["0.77", "0.87"]
    on_it = [m for m in fusion.prims.values() if abs(m.primitive.obb.center[0] - 0.9) < 0.01]
    assert on_it[0].id not in fusion.scene_model().unstable_ids


def test_what_lies_on_a_tray_on_a_table_rests_on_the_tray_alone():
    """Support is direct (thesis 3.2.2's graph): a cup on a tray on a table is held by the
    tray, not by the table as well, though its bottom is within ``rest_tolerance`` of both
    tops and a view reported both; a cup on the table beside the tray keeps the table."""
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    tray = box(1, (0.9, 0.0, 0.74), (0.4, 0.3, 0.04))  # top at 0.76
    on_tray = box(2, (0.9, 0.0, 0.81), (0.08, 0.08, 0.1))  # bottom at 0.76
    beside = box(3, (1.3, 0.0, 0.77), (0.08, 0.08, 0.1))  # bottom at 0.72, by the tray
    edges = [(0, 1), (1, 2), (0, 2), (0, 3), (1, 3)]
    names = {0: "table", 1: "tray", 2: "cup on tray", 3: "cup on table"}
    direct = {("table", "tray"), ("tray", "cup on tray"), ("table", "cup on table")}
    for nearer, expected in ((FusionConfig.nearer_top, direct),
                             (np.inf, direct | {("table", "cup on tray")})):  # fmt: skip
        fusion = Fusion(FusionConfig(nearer_top=nearer))
        update = fusion.update(observation(0, [table, tray, on_tray, beside], edges))
        name = {update.mapping[i]: n for i, n in names.items()}
        assert {(name[a], name[b]) for a, b in fusion.support()} == expected
        # the model's edges are these, and all four rest
        model = fusion.scene_model()
        assert len(model.support_edges) == len(expected) and not model.unstable_ids


def test_a_wall_behind_a_counter_does_not_rest_on_the_counter():
    """The kitchen's back wall, seen above the counter that hides its foot: a view reported
    counter → wall (they touch, the wall's visible bottom at the counter's top). Structure
    rests on nothing above the floor; the floor's own edge to it stays."""
    T = facing_wall(2.0)
    floor = plane(0, (0.5, 2.99), (-1.0, 1.0), 0.0)
    counter = plane(1, (2.4, 2.99), (-1.0, 1.0), 0.9)  # its top, against the wall
    room = wall(2, (-1.0, 1.0), 3.0, (0.9, 2.0))  # the wall above the counter
    jar = box(3, (2.7, 0.0, 0.98), (0.1, 0.1, 0.16))
    edges = [(1, 2), (0, 2), (1, 3), (0, 1)]
    rests = {("floor", "counter"), ("floor", "wall"), ("counter", "jar")}
    # floor_max = ∞: everything counts as the floor's height, the rule never applies; the
    # wall then rests on the counter (and, nearer its top, not on the floor: ``nearer_top``)
    held = {("floor", "counter"), ("counter", "wall"), ("counter", "jar")}
    for floor_max, expected in ((FusionConfig.floor_max, rests), (np.inf, held)):
        fusion = Fusion(FusionConfig(floor_max=floor_max))
        update = fusion.update(observation(0, [floor, counter, room, jar], edges, T=T))
        name = {update.mapping[i]: n for i, n in enumerate(["floor", "counter", "wall", "jar"])}
        assert {(name[a], name[b]) for a, b in fusion.support()} == expected


def test_pieces_and_edge_faces_of_a_table_top_do_not_rest_on_it():
    """A table top fused as two pieces (a plane and a slab fitted to its edge, tops level) and
    a face of its front edge: views reported slab → plane (the plane's bottom within
    ``rest_tolerance`` of the slab's top) and plane → face, which the live stack's score counted
    as "table supports table". What does not rise ``level_with`` above a ground surface's top
    is a part of it, not on it; a tray 4 cm over the table still rests on it, a cup on it."""
    table = plane(0, (0.2, 0.9), (-0.6, 0.6), 0.72)
    piece = box(1, (1.25, 0.0, 0.705), (0.6, 1.2, 0.03))  # top at 0.72, beside the plane
    cup = box(2, (0.5, 0.0, 0.77), (0.08, 0.08, 0.1))  # bottom at 0.72
    tray = box(3, (1.3, 0.2, 0.74), (0.4, 0.6, 0.04))  # top at 0.76: a ground surface too
    face = wall(4, (-0.6, 0.6), 0.2, (0.70, 0.72))  # the plane's front edge, 2 cm deep
    edges = [(1, 0), (0, 1), (0, 2), (1, 3), (0, 4)]
    names = ["table", "piece", "cup", "tray", "face"]
    rests = {("table", "cup"), ("piece", "tray")}
    for level_with, expected in (
        (FusionConfig.level_with, rests),
        # without the rule (nor over_margin's, for the plane's centre is not over the slab):
        # the slab holds the plane up (the plane's bottom at the slab's top; the slab's
        # bottom, 3 cm under the plane, keeps the reverse edge out), the plane its face
        (-np.inf, rests | {("piece", "table"), ("table", "face")}),
    ):
        over = FusionConfig.over_margin if np.isfinite(level_with) else np.inf
        fusion = Fusion(FusionConfig(level_with=level_with, over_margin=over))
        update = fusion.update(observation(0, [table, piece, cup, tray, face], edges))
        assert len(fusion.prims) == 5
        name = {update.mapping[i]: n for i, n in enumerate(names)}
        assert {(name[a], name[b]) for a, b in fusion.support()} == expected


def test_what_stands_beside_a_shelf_board_does_not_rest_on_it():
    """A shelf board with a side panel's top beside it (3 cm thick, 3.5 cm above the board,
    its centre 1.5 cm past the board's edge) and a box on the board: views report the board
    holding both up. What rests on a ground surface has its centre over it (``over_margin``):
    the panel's top is not on the board, the box is."""
    board = plane(0, (1.3, 1.7), (-0.5, 0.5), 1.065)
    panel_top = box(1, (1.5, 0.515, 1.0825), (0.4, 0.03, 0.035))
    stack = box(2, (1.5, 0.1, 1.115), (0.16, 0.16, 0.1))
    names = ["board", "panel", "box"]
    for margin, expected in (
        (FusionConfig.over_margin, {("board", "box")}),
        (np.inf, {("board", "box"), ("board", "panel")}),  # without the rule
    ):
        fusion = Fusion(FusionConfig(over_margin=margin))
        update = fusion.update(observation(0, [board, panel_top, stack], [(0, 1), (0, 2)]))
        name = {update.mapping[i]: n for i, n in enumerate(names)}
        assert {(name[a], name[b]) for a, b in fusion.support()} == expected
