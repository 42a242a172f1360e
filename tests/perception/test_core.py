"""Invariants of the perception core on plain arrays: fits recover known shapes, boxes
intersect as geometry says, bad frames give empty observations, the scores count right."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments import evaluation
from schemas import (
    BoxModel,
    CameraIntrinsics,
    GroundTruth,
    GroundTruthObject,
    Obb,
    PlaneModel,
    Primitive,
)
from services.perception import ransac
from services.perception.obb import Box, intersect, plane_box
from services.perception.pipeline import Perception

RNG = np.random.default_rng(7)


def _noisy(points: np.ndarray, sigma: float = 0.002) -> np.ndarray:
    return points + RNG.normal(0, sigma, points.shape)


def test_plane_fit_recovers_the_plane_among_outliers():
    n = np.array([0.2, -0.3, 0.93])
    n /= np.linalg.norm(n)
    e1 = np.cross(n, [1, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    uv = RNG.uniform(-0.5, 0.5, (2000, 2))
    X = _noisy(uv[:, :1] * e1 + uv[:, 1:] * e2 + 0.4 * n)
    X = np.concatenate([X, RNG.uniform(-1, 1, (500, 3))])
    N = np.tile(n, (len(X), 1))
    fit = ransac.fit_plane(X, N, np.random.default_rng(0), 0.01, 0.9)
    assert math.degrees(math.acos(abs(fit.normal @ n))) < 1
    assert abs(abs(fit.d) - 0.4) < 0.003
    assert fit.count >= 1990


def test_plane_hypotheses_are_scored_on_every_point_without_a_subset():
    """Two parallel planes of 2100 and 1900 points: scored on all of them (``subset=None``),
    the fit takes the larger plane whatever the seed; scored on ``SUBSET`` points drawn at
    random (the default), it takes the smaller one for the seeds whose draw holds more of its
    points."""
    rng = np.random.default_rng(11)
    uv = rng.uniform(-0.5, 0.5, (4000, 2))
    z = np.where(np.arange(4000) < 2100, 0.0, 0.3) + rng.normal(0, 0.002, 4000)
    X = np.column_stack([uv, z])
    N = np.tile([0.0, 0.0, 1.0], (len(X), 1))
    d = {
        size: np.array([
            abs(ransac.fit_plane(X, N, np.random.default_rng(s), 0.01, 0.9, 96, size).d)
            for s in range(40)
        ])
        for size in (None, ransac.SUBSET)
    }  # fmt: skip
    assert np.all(d[None] < 0.005)  # z = 0, the larger
    assert 0 < np.sum(np.abs(d[ransac.SUBSET] - 0.3) < 0.005) < 20
    full = ransac.fit_plane(X, N, np.random.default_rng(0), 0.01, 0.9, 96, None)
    assert full.count >= 2090 and len(full.inliers) == len(X)


def test_cylinder_fit_recovers_radius_and_axis_from_a_visible_arc():
    axis = np.array([0.0, 0.3, 1.0])
    axis /= np.linalg.norm(axis)
    e1 = np.cross(axis, [1, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    theta = RNG.uniform(-1.2, 1.2, 1500)  # 140° of arc, as a camera sees it
    t = RNG.uniform(-0.08, 0.08, 1500)
    radial = np.outer(np.cos(theta), e1) + np.outer(np.sin(theta), e2)
    centre = np.array([1.0, 0.2, 0.8])
    X = _noisy(centre + 0.035 * radial + np.outer(t, axis))
    fit = ransac.fit_cylinder(X, radial, np.random.default_rng(0), 0.006, 0.9, 0.01, 0.25)
    assert abs(fit.radius - 0.035) < 0.002
    assert math.degrees(math.acos(abs(fit.axis @ axis))) < 2
    assert ransac.cylinder_arc(radial, fit.axis) > 120


def test_sphere_fit_recovers_centre_and_radius():
    d = RNG.normal(size=(1500, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    d = d[d[:, 0] < 0.2]  # the half the camera sees
    X = _noisy(np.array([0.5, -0.2, 0.9]) + 0.05 * d)
    fit = ransac.fit_sphere(X, d, np.random.default_rng(0), 0.006, 0.9, 0.01, 0.25)
    assert abs(fit.radius - 0.05) < 0.002
    assert np.linalg.norm(fit.center - [0.5, -0.2, 0.9]) < 0.003


def _box(center, yaw=0.0, extent=(1, 1, 1)) -> Box:
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return Box(np.array(center, float), R, np.array(extent, float))


def test_obb_intersection_and_epsilon():
    a = _box([0, 0, 0])
    assert intersect(a, _box([0.9, 0, 0]))
    assert not intersect(a, _box([1.04, 0, 0]))
    assert intersect(a, _box([1.04, 0, 0]), epsilon=0.05)  # Eq. 3.6: ε-extended
    assert not intersect(a, _box([1.2, 1.2, 0], yaw=math.pi / 4))
    assert intersect(a, _box([1.2, 0, 0], yaw=math.pi / 4))  # a corner reaches in


def test_plane_box_is_the_minimal_rectangle():
    angle = 0.3
    R = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    uv = RNG.uniform([-0.4, -0.1], [0.4, 0.1], (3000, 2)) @ R.T
    X = np.column_stack([uv, np.full(len(uv), 0.75)])
    box = plane_box(X, np.array([0, 0, 1.0]))
    assert sorted(box.extent[:2]) == pytest.approx([0.2, 0.8], abs=0.01)
    assert np.linalg.det(box.rotation) == pytest.approx(1.0)


@pytest.mark.parametrize("kind", ["zeros", "nan", "inf", "single", "noise", "negative"])
def test_bad_frames_give_empty_observations(kind):
    depth = {
        "zeros": np.zeros((480, 640)),
        "nan": np.full((480, 640), np.nan),
        "inf": np.full((480, 640), np.inf),
        "single": np.pad([[1.0]], ((0, 479), (0, 639))),
        "noise": np.random.default_rng(0).uniform(0.35, 3.0, (480, 640)),
        "negative": -np.ones((480, 640)),
    }[kind].astype(np.float32)
    result = Perception().perceive(depth, None, CameraIntrinsics.from_fov(640, 480, 45), np.eye(4))
    assert result.primitives == [] and result.support == [] and result.affordances == []
    assert result.points == {"noise": 76800, "single": 1}.get(kind, 0)


def _plane_primitive(pid: int, z: float, size: float) -> Primitive:
    return Primitive(
        id=pid,
        model=PlaneModel(normal=np.array([0, 0, 1.0]), d=-z),
        obb=Obb(
            center=np.array([0, 0, z]), rotation=np.eye(3), extent=np.array([size, size, 0.01])
        ),
        inlier_count=100,
        inliers=np.zeros((0, 3), np.float32),
    )


def test_inlier_and_overlapping_index_count_points():
    grid = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 21), np.linspace(-0.5, 0.5, 21)), -1)
    floor = np.column_stack([grid.reshape(-1, 2), np.zeros(441)])
    segments = {"floor": floor}
    full = evaluation.score_primitives(segments, [_plane_primitive(0, 0.0, 1.2)])
    assert full.inlier_index == 1.0 and full.overlapping_index == 1.0
    half = evaluation.score_primitives(segments, [_plane_primitive(0, 0.0, 0.52)])
    # an OBB over the middle: 11×11 of 21×21 points inside (Eq. 3.8)
    assert half.inlier_index == pytest.approx(121 / 441, abs=0.03)
    assert half.overlapping_index == pytest.approx(121 / 441, abs=0.03)
    assert evaluation.score_primitives(segments, [_plane_primitive(0, 0.5, 1.2)]).inlier_index == 0


def _gt(edges):
    objs = [
        GroundTruthObject(name=n, kind="box", pose=np.eye(4), size=np.ones(3))
        for n in ("table", "a", "b", "c")
    ]
    return GroundTruth(
        scene="s", robot="r", objects=objs, support_edges=edges, support_closure=edges
    )


def test_support_f1_follows_eq_4_14_to_4_16_and_every_edge_counts():
    gt = _gt([("table", "a"), ("a", "b"), ("table", "c")])
    bodies = {0: "table", 1: "a", 2: "b", 3: "a", 4: "c"}  # 1 and 3 are two faces of a
    perfect = evaluation.score_support(gt, [(0, 1), (3, 2), (0, 4), (0, 3)], bodies)
    assert (perfect.precision, perfect.recall, perfect.f1) == (1.0, 1.0, 1.0)  # 0→1, 0→3 once
    # an edge inside one body is a false positive, not dropped
    inner = evaluation.score_support(gt, [(0, 1), (3, 2), (0, 4), (1, 3)], bodies)
    assert inner.precision == pytest.approx(3 / 4) and inner.recall == 1.0
    assert inner.false_positives == [("a", "a")]
    wrong = evaluation.score_support(gt, [(0, 1), (2, 3)], {0: "table", 1: "a", 2: "b", 3: "a"})
    # edges: table→a true, b→a false; table→c and a→b missing
    assert wrong.precision == pytest.approx(1 / 2)
    assert wrong.recall == pytest.approx(1 / 3)
    assert wrong.f1 == pytest.approx(2 * 0.5 * (1 / 3) / (0.5 + 1 / 3))


def test_spurious_primitives_and_edges_make_precision_fall():
    """A perfect observation scores 1.0; two spurious primitives that map to no body, with an
    edge each, are two false positives (the scoring that dropped them said 1.0)."""
    gt = _gt([("table", "a"), ("a", "b"), ("table", "c")])
    bodies = {0: "table", 1: "a", 2: "b", 3: "c"}
    edges = [(0, 1), (1, 2), (0, 3)]
    assert evaluation.score_support(gt, edges, bodies).f1 == 1.0
    spurious = evaluation.score_support(gt, [*edges, (0, 7), (7, 8)], bodies)  # 7, 8: no body
    assert spurious.precision == pytest.approx(3 / 5) and spurious.recall == 1.0
    assert spurious.f1 == pytest.approx(0.75)
    assert spurious.false_positives == [("#7", "#8"), ("table", "#7")]
    assert evaluation.edge_names([(0, 7)], bodies) == [("table", "#7")]
    # edges between bodies one of which is outside the region of interest are not judged;
    # an edge from a primitive of no body is judged (a false positive) wherever its other end
    # is: the table (here outside the region) under a spurious primitive is no excuse for it
    outside = evaluation.score_support(gt, [*edges, (0, 7), (7, 1)], bodies, scope={"a", "b"})
    assert outside.edges == [("#7", "a"), ("a", "b"), ("table", "#7")]
    assert outside.false_positives == [("#7", "a"), ("table", "#7")]
    assert outside.precision == pytest.approx(1 / 3) and outside.recall == 1.0
    # nothing to find and nothing found is right; something found where nothing is, is not
    empty = _gt([])
    assert evaluation.score_support(empty, [], bodies).f1 == 1.0
    assert evaluation.score_support(empty, [(0, 1)], bodies).f1 == 0.0


def test_vertex_scores_see_unmapped_split_and_merged_primitives():
    grid = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 21), np.linspace(-0.5, 0.5, 21)), -1)
    floor = np.column_stack([grid.reshape(-1, 2), np.zeros(441)])
    shelf = floor + np.array([0, 0, 0.5])
    segments = {"floor": floor, "shelf": shelf}
    halves = [_plane_primitive(0, 0.0, 1.2), _plane_primitive(1, 0.5, 1.2)]
    good = evaluation.score_primitives(segments, halves)
    assert good.vertex_precision == 1.0 and good.bodies_merged == 0
    assert good.segments_per_body == {"floor": 1, "shelf": 1}
    phantom = _plane_primitive(2, 1.5, 1.2)  # explains no ground-truth point
    both = Primitive(  # one box around floor and shelf: half its points on each
        id=3,
        model=BoxModel(center=np.array([0, 0, 0.25]), rotation=np.eye(3),
                       extent=np.array([1.2, 1.2, 0.5])),
        obb=Obb(center=np.array([0, 0, 0.25]), rotation=np.eye(3),
                extent=np.array([1.2, 1.2, 0.5])),
        inlier_count=100, inliers=np.zeros((0, 3), np.float32),
    )  # fmt: skip
    split = [*halves, _plane_primitive(4, 0.0, 1.2), phantom, both]
    bad = evaluation.score_primitives(segments, split)
    assert bad.vertex_precision == pytest.approx(3 / 5)  # the phantom and the box map nowhere
    assert bad.segments_per_body == {"floor": 2, "shelf": 1}
    assert bad.bodies_merged == 1 and bad.merged == {3: ["floor", "shelf"]}
