"""Perception on simulated frames with depth noise on: the right primitive kind for every
object, its parameters within tolerance, InlierIndex / OverlappingIndex, support F1, and the
object whose support is hidden flagged unstable."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments import evaluation
from services.perception.pipeline import Perception, observation
from services.sim import capture
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR6
from services.sim.world import World, look_target

_views: dict = {}


def start_view(scene: str, seed: int):
    """The start view of ``scene`` (robot_start, looking at the roi centre), perceived."""
    if (scene, seed) not in _views:
        world = World(scene, ARMAR6)
        world.look_at(look_target(world))
        renderer = CameraRenderer(world.model, 640, 480)
        frame, gt = capture.view(world, renderer, "head_rgbd", np.random.default_rng(seed))
        renderer.close()
        perception = Perception()
        result = perception.perceive(frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera)
        obs = observation(result, frame, 0, "test", 3.0, perception.config.stride)
        segments = evaluation.labelled_points(
            gt, frame.depth, frame.intrinsics, frame.T_world_camera
        )
        scores = evaluation.score_primitives(segments, obs.primitives)
        visible = {
            name: int(np.sum((gt.segmentation == i) & (frame.depth > 0.35) & (frame.depth < 3.0)))
            for i, name in enumerate(gt.labels)
        }
        _views[scene, seed] = (gt, obs, scores, visible)
    return _views[scene, seed]


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(
        math.acos(min(1.0, abs(float(a @ b)) / np.linalg.norm(a) / np.linalg.norm(b)))
    )


@pytest.mark.parametrize("seed", [0, 1])
def test_every_visible_object_gets_a_primitive_of_its_kind_and_size(seed):
    gt, obs, scores, visible = start_view("tabletop_clutter", seed)
    by_id = {p.id: p for p in obs.primitives}
    checked = []
    for obj in gt.objects:
        if obj.kind == "compound" or visible.get(obj.name, 0) < 500:
            continue
        p = by_id[scores.match[obj.name]]  # ψ(G_i), Eq. 3.10
        m = p.model
        assert m.kind == obj.kind, f"{obj.name}: {m.kind} instead of {obj.kind}"
        axis = obj.pose[:3, 2]
        if m.kind == "plane":
            assert _angle(m.normal, axis) < 3, obj.name
        elif m.kind == "cylinder":
            assert abs(m.radius - obj.size[0] / 2) < 0.005, (obj.name, m.radius)
            assert _angle(m.axis, axis) < 5, obj.name
        elif m.kind == "sphere":
            assert abs(m.radius - obj.size[0] / 2) < 0.005, (obj.name, m.radius)
        else:
            np.testing.assert_allclose(
                np.sort(m.extent), np.sort(obj.size), atol=0.01, err_msg=obj.name
            )
        checked.append(obj.name)
    assert len(checked) >= 8  # the eight objects on the table


def test_inlier_and_overlapping_index_on_the_clutter_start_view():
    _, _, scores, _ = start_view("tabletop_clutter", 0)
    assert scores.inlier_index >= 0.85
    assert scores.overlapping_index >= 0.7


def test_single_view_support_f1_is_one_where_every_contact_is_visible():
    gt, obs, scores, _ = start_view("tabletop_clutter", 0)
    support = evaluation.score_support(
        gt, [(e.supporter, e.supported) for e in obs.support_edges], scores.bodies
    )
    assert support.f1 == 1.0, support


def test_the_object_whose_support_is_hidden_is_flagged_unstable():
    gt, obs, scores, _ = start_view("tabletop_occluded", 0)
    unstable = {scores.bodies.get(i) for i in obs.unstable_ids}
    assert "cylinder_top" in unstable
    assert not {"box_front", "cup"} & unstable
    support = evaluation.score_support(
        gt, [(e.supporter, e.supported) for e in obs.support_edges], scores.bodies
    )
    assert support.precision == 1.0 and support.recall < 1.0  # the hidden contact is missing


def test_on_an_open_shelf_the_boards_hold_the_stack_and_the_cup():
    """The shelf's boards are found as level planes, not taken into "boxes" with the side
    panels they meet at concave edges, so the stack on the upper board and the cup on the lower
    one rest on them; the stack's own edge is found too (before the convexity test, F1 0.4 at
    the start view: no board, no edge from it)."""
    gt, obs, scores, _ = start_view("shelf", 0)
    support = evaluation.score_support(
        gt, [(e.supporter, e.supported) for e in obs.support_edges], scores.bodies
    )
    assert {("shelf", "box_base"), ("shelf", "cup"), ("box_base", "cylinder_top")} <= set(
        support.edges
    ), support
    boards = [p for p in obs.primitives if p.model.kind == "plane" and abs(p.model.normal[2]) > 0.99
              and scores.bodies.get(p.id) == "shelf"]  # fmt: skip
    heights = sorted(round(-p.model.d, 2) for p in boards if np.ptp(p.obb.extent) > 0.3)
    assert heights[-2:] == [0.47, 1.07] or heights[-2:] == [0.46, 1.06], heights


def test_affordances_fit_the_hand():
    _, obs, scores, _ = start_view("tabletop_clutter", 0)
    kinds = {(a.kind, scores.bodies.get(a.primitive_id)) for a in obs.affordances}
    assert {("grasp", "can"), ("grasp", "ball"), ("grasp", "bottle"), ("support", "table")} <= kinds
    assert ("lift", "crate") in kinds  # too wide for one hand
    assert not any(k == "grasp" and b in ("table", "crate") for k, b in kinds)
    for a in obs.affordances:
        assert a.poses.shape[1:] == (4, 4) and 0 < a.confidence <= 1
        assert a.bimanual == (a.poses.shape[0] == 2)
