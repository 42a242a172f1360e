"""Utility (Eq. 4.10-4.13), the strategies, and the top-down saliency (Eq. 4.5)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas import BoxModel, Obb, PlaneModel, Primitive, SceneModel, SupportEdge
from services.nbv import topdown
from services.nbv.utility import normalise, utility

RNG = np.random.default_rng(0)


def test_normalisation_maps_gain_and_cost_into_0_1():
    gain = np.array([10.0, 250.0, 40.0, 1e6])
    cost = np.array([3.0, 12.0, math.inf, 7.0])
    ok = np.isfinite(cost)
    g, c = normalise(gain, ok), normalise(cost, ok)
    assert g[ok].min() == 0.0 and g[ok].max() == 1.0 and np.all((g >= 0) & (g <= 1))
    assert c[ok].min() == 0.0 and c[ok].max() == 1.0 and c[2] == 0.0
    assert g[3] == 1.0 and g[1] == pytest.approx((250 - 10) / (1e6 - 10))


def test_strategies():
    gain = np.array([100.0, 90.0, 10.0, 500.0])
    cost = np.array([20.0, 2.0, 1.0, math.inf])  # the richest view is unreachable
    saliency = np.array([0.2, 0.1, 0.9, 1.0])
    u = {
        s: utility(s, gain, cost, saliency, 0.5, RNG) for s in ("utility", "occupancy", "saliency")
    }
    assert all(v[3] == -np.inf for v in u.values())
    assert np.argmax(u["occupancy"]) == 0  # IG only: the far view
    assert np.argmax(u["utility"]) == 1  # almost the same IG, a tenth of the way
    assert np.argmax(u["saliency"]) == 2
    assert u["utility"][1] == pytest.approx(80 / 90 - 0.5 * 1 / 19)  # Eq. 4.13
    r = utility("random", gain, cost, saliency, 0.5, RNG)
    assert np.all((r[:3] >= 0) & (r[:3] < 1)) and r[3] == -np.inf
    with pytest.raises(ValueError, match="unknown strategy"):
        utility("greedy", gain, cost, saliency, 0.5, RNG)


def test_edge_saliency_eq_4_5():
    assert topdown.edge_saliency(0, 5) == pytest.approx(1.0)  # never seen: most interesting
    assert topdown.edge_saliency(5, 5) == pytest.approx(0.75)  # seen every time: λ_s
    assert topdown.edge_saliency(2, 4) == pytest.approx(0.75 + 0.25 * math.cos(math.pi / 4))


def test_largest_arc_between_previous_views():
    middle, width = topdown.largest_arc([0.0, math.pi / 2, math.pi])
    assert width == pytest.approx(math.pi) and middle == pytest.approx(3 * math.pi / 2)
    assert topdown.largest_arc([]) == (0.0, 2 * math.pi)


def _box(pid, centre, extent):
    c, e = np.array(centre, float), np.array(extent, float)
    return Primitive(id=pid, model=BoxModel(center=c, rotation=np.eye(3), extent=e),
                     obb=Obb(center=c, rotation=np.eye(3), extent=e), inlier_count=100,
                     inliers=np.zeros((1, 3), np.float32))  # fmt: skip


def test_points_of_interest_algorithm_3():
    table = Primitive(
        id=0, model=PlaneModel(normal=np.array([0.0, 0, 1]), d=-0.75),
        obb=Obb(center=np.array([0.0, 0, 0.75]), rotation=np.eye(3),
                extent=np.array([1.2, 0.8, 0.01])),
        inlier_count=100, inliers=np.zeros((1, 3), np.float32),
    )  # fmt: skip
    supported = _box(1, (0.2, 0.0, 0.8), (0.1, 0.1, 0.1))
    floating = _box(2, (-0.3, 0.1, 0.85), (0.1, 0.2, 0.2))  # nothing holds it: data missing
    scene = SceneModel(
        seq=0, stamp=0.0, model_version=1, n_views=4, fusion="sg",
        primitives=[table, supported, floating], root_id=0,
        support_edges=[SupportEdge(supporter=0, supported=1, occ=1)],
    )  # fmt: skip
    visited = np.array([[-1.5, 0.0], [0.0, -1.5]])  # views from the west and the south
    pois = topdown.points_of_interest(scene, np.zeros(3), visited)
    assert len(pois) == 2
    edge = next(p for p in pois if p.saliency < 1)
    assert edge.saliency == pytest.approx(topdown.edge_saliency(1, 4))
    assert edge.x == pytest.approx([0.2, 0.0, 0.75])  # where the box meets the table
    lone = next(p for p in pois if p.saliency == 1)
    # the middle of the largest arc (between south, west: through north and east) is 45°
    assert lone.azimuth == pytest.approx(math.radians(45))
    assert lone.x == pytest.approx([-0.3 + 0.05, 0.1 + 0.05, 0.85])  # leaving its OBB at 45°


def test_an_occluded_point_of_interest_gets_its_saliency_inverted():
    voxel, origin = 0.05, np.array([-2.0, -2.0, 0.0])
    states = np.ones((80, 80, 50), np.uint8)
    poi = topdown.PoI(np.array([0.0, 0.0, 0.8]), 0.9, 0.0)  # the view lies east of it
    t = np.zeros((0, 3))
    _, s = topdown.saliency(
        t, [poi], math.radians(62), 1.5, np.array([0, 0, 0.8]), states, origin, voxel
    )
    assert s[-1] == pytest.approx(0.9)
    states[50:52, 30:50, 10:40] = 2  # a wall at x = 0.5 between the PoI and the view
    _, s = topdown.saliency(
        t, [poi], math.radians(62), 1.5, np.array([0, 0, 0.8]), states, origin, voxel
    )
    assert s[-1] == pytest.approx(0.1)
