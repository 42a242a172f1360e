"""The first view: from where the robot stands, looking at the scene; a start facing away
turns the platform in place first (the neck turns ±45° only)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.common.robots import robot_mjcf
from services.nbv.planner import Planner, PlannerConfig
from services.nbv.view_sphere import wrap

CENTRE = np.array([1.3, 0.0, 0.9])


@pytest.fixture(scope="module")
def planner() -> Planner:
    return Planner(PlannerConfig(), robot_mjcf("armar6"), "head_rgbd", "armar6")


@pytest.mark.parametrize("yaw", [math.pi, -math.pi / 2, 2.0, math.pi / 2 + 0.3])
def test_a_start_facing_away_turns_toward_the_scene(planner, yaw):
    base, sol = planner.first_view((-1.0, 0.5, yaw), CENTRE)
    assert base[:2] == (-1.0, 0.5)
    assert abs(wrap(base[2] - math.atan2(-0.5, 2.3))) < 1e-9
    assert sol.aim_error < math.radians(1)
    T = sol.T_world_camera  # the optical axis passes through the centre
    d = CENTRE - T[:3, 3]
    assert np.linalg.norm(np.cross(T[:3, 2], d / np.linalg.norm(d))) < 0.02


def test_a_start_the_neck_can_aim_from_stays_where_it_is(planner):
    start = (-1.0, 0.5, 0.4)  # 0.6 rad off: within the neck's 45°
    base, sol = planner.first_view(start, CENTRE)
    assert base == start and sol.aim_error < math.radians(1)
    assert abs(sol.joints["neck_yaw"]) > 0.3


def test_no_candidates_says_why():
    from services.nbv.path_cost import FloorMap, PathPlanner

    states = np.ones((100, 100, 60), np.uint8)
    states[40:60, 40:60, 10:40] = 2  # a pillar where the platform stands
    floor = FloorMap.from_states(states, np.array([-1.0, -1.0, 0.0]), 0.02)
    planner = PathPlanner(floor, 0.45, 0.5, 1.0)
    why = Planner.why_no_candidates(planner, (0.0, 0.0, 0.0), (12, 10))
    assert why.startswith("the platform at (0.00, 0.00) is boxed in") and "0.50 m" in why
    assert "inverse kinematics" in Planner.why_no_candidates(planner, (0, 0, 0), (0, 0))
    assert "known obstacles" in Planner.why_no_candidates(planner, (0, 0, 0), (7, 0))
    assert "none of the 10" in Planner.why_no_candidates(planner, (-0.9, -0.9, 0), (12, 10))


def test_views_whose_platform_pose_is_in_collision_get_no_information_gain(planner):
    """IG is predicted only for views a path may reach: a view whose platform pose lies in an
    obstacle has c = ∞ for every strategy, so its rays are not cast (gain 0, never chosen)."""
    voxel, origin = 0.04, np.array([-1.5, -2.5, 0.0])
    states = np.full((125, 125, 50), 1, np.uint8)  # free
    x = origin[0] + (np.arange(125) + 0.5) * voxel
    z = origin[2] + (np.arange(50) + 0.5) * voxel
    states[np.ix_(x > 2.0, np.arange(125), (z > 0.1) & (z < 0.8))] = 2  # a block behind
    k = np.floor((CENTRE - origin) / voxel).astype(int)
    states[k[0] - 5 : k[0] + 5, k[1] - 5 : k[1] + 5, : k[2] - 2] = 2  # the table
    states[k[0] - 5 : k[0] + 5, k[1] - 5 : k[1] + 5, k[2] - 2 : k[2] + 5] = 0  # unknown on it
    sent: list[int] = []

    def coarse(poses: np.ndarray) -> np.ndarray:
        sent.append(len(poses))
        return planner.coarse(states, origin, voxel, poses)

    planner.coarse_gains = coarse
    try:
        r = planner.plan(CENTRE[None], None, states, origin, voxel, (0.0, 0.0, 0.0),
                         np.zeros((1, 3)), 1)  # fmt: skip
    finally:
        planner.coarse_gains, planner.first_gain = None, None
    n, bx = len(r.candidates.t), r.candidates.base[:, 0]
    skipped = r.gain == 0
    assert sent == [n - skipped.sum()]  # IG cast for the others only
    assert 10 < skipped.sum() < n - 10  # both kinds of view are sampled
    # skipped: the platform's footprint (0.45 m + 0.05 m margin) reaches into the block
    assert np.all(bx[skipped] > 2.0 - 0.5 - 0.1) and np.all(np.isinf(r.cost[skipped]))
    assert np.all(skipped[bx > 2.0 - 0.5 + 0.1])
    assert np.isfinite(r.cost[~skipped]).all()
    assert r.best is not None and not skipped[r.best]


def test_an_excluded_goal_is_not_planned_again(planner):
    """A goal the platform could not reach (``PlanRequest.excluded``): every candidate within
    EXCLUDED_RADIUS of it is unreachable (c = ∞), and the best view is another one, away from
    it; without the exclusion the same map gives that goal back."""
    from schemas.planning import EXCLUDED_RADIUS

    voxel, origin = 0.04, np.array([-1.5, -2.5, 0.0])
    states = np.full((125, 125, 50), 1, np.uint8)
    k = np.floor((CENTRE - origin) / voxel).astype(int)
    states[k[0] - 5 : k[0] + 5, k[1] - 5 : k[1] + 5, : k[2] - 2] = 2  # the table
    states[k[0] - 5 : k[0] + 5, k[1] - 5 : k[1] + 5, k[2] - 2 : k[2] + 5] = 0  # unknown on it

    def plan(excluded: np.ndarray | None):
        try:
            return planner.plan(CENTRE[None], None, states, origin, voxel, (0.0, 0.0, 0.0),
                                np.zeros((1, 3)), 1, excluded)  # fmt: skip
        finally:
            planner.first_gain = None

    first = plan(None)
    goal = first.candidates.base[first.best]
    again = plan(goal[None])
    base = again.candidates.base
    near = np.linalg.norm(base[:, :2] - goal[:2], axis=1) < EXCLUDED_RADIUS
    assert near.any() and np.isinf(again.cost[near]).all()
    assert again.best is not None and not near[again.best]
    assert np.linalg.norm(base[again.best, :2] - goal[:2]) >= EXCLUDED_RADIUS


def test_paths_go_round_where_the_platform_got_stuck(planner):
    """A glass pane the map does not hold: the platform drove +x from (0, 0) and stood
    against it. The next paths from there keep clear of an obstacle just ahead of its
    footprint in that direction, and the stuck pose itself stays free to start from."""
    from itertools import pairwise

    from schemas.planning import BLOCKED_RADIUS

    voxel, origin = 0.04, np.array([-1.5, -2.5, 0.0])
    states = np.full((125, 125, 50), 1, np.uint8)  # all free
    stuck = np.array([[0.0, 0.0, 1.0, 0.0]])
    start, goal = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    free = planner.path_planner(states, origin, voxel, start)
    cost, path = free.cost(start, goal)
    assert len(path) == 2  # the straight line, without it
    paths = planner.path_planner(states, origin, voxel, start, stuck)
    assert paths.valid(start[None, :2])[0]
    for _ in range(10):  # RRT is random
        cost, path = paths.cost(start, goal)
        assert math.isfinite(cost) and len(path) > 2
        for a, b in pairwise(path):
            pts = a[:2] + np.linspace(0, 1, 500)[:, None] * (b[:2] - a[:2])
            bump = np.array([paths.need + BLOCKED_RADIUS + 0.03, 0.0])
            assert np.linalg.norm(pts - bump, axis=1).min() >= paths.need + BLOCKED_RADIUS - voxel


def test_a_platform_boxed_in_by_unseen_floor_looks_around_from_where_it_stands(planner):
    """The kitchen's first view saw the table behind the robot's back; every view of its
    view sphere lies beyond floor no view has seen (in the roi: no path). The robot turns
    in place toward the direction with the most unknown space and looks, instead of ending
    the episode with no candidate; where unknown floor is free to cross it does not."""
    from dataclasses import replace

    from services.nbv.planner import LOOK_DIRECTIONS

    voxel, origin = 0.05, np.array([-3.0, -3.0, 0.0])
    states = np.zeros((120, 120, 40), np.uint8)  # never seen
    x = origin[0] + (np.arange(120) + 0.5) * voxel
    states[x < -0.9] = 1  # seen and free: the part behind the robot at x = −1
    roi = (np.array([-3.0, -3.0, 0.0]), np.array([3.0, 3.0, 2.0]))
    config = planner.config
    try:
        planner.config = replace(config, roi=roi)
        boxed = planner.plan(CENTRE[None], None, states, origin, voxel, (-1.0, 0.0, math.pi),
                             np.zeros((1, 3)), 1)  # fmt: skip
        planner.first_gain = None
        planner.config = replace(config, roi=None)
        free = planner.plan(CENTRE[None], None, states, origin, voxel, (-1.0, 0.0, math.pi),
                            np.zeros((1, 3)), 1)  # fmt: skip
    finally:
        planner.config, planner.first_gain = config, None
    around = boxed.candidates.base[-LOOK_DIRECTIONS:]
    assert boxed.looked_around and boxed.best is not None and not boxed.terminate
    assert np.isinf(boxed.cost[:-LOOK_DIRECTIONS]).all()  # no sphere view has a path
    assert np.allclose(around[:, :2], [-1.0, 0.0])  # turned in place
    b = boxed.best
    assert b >= len(boxed.cost) - LOOK_DIRECTIONS
    # toward the unknown half (+x), the turn its cost (π − |yaw| at 1 rad/s)
    yaw = boxed.candidates.base[b, 2]
    assert abs(yaw) < math.pi / 2, yaw
    assert boxed.cost[b] == pytest.approx(math.pi - abs(yaw))
    assert boxed.gain[b] > 0 and np.array_equal(boxed.path[:, :2], [[-1.0, 0.0]] * 2)
    assert not free.looked_around and free.best is not None
    assert np.linalg.norm(free.candidates.base[free.best, :2] - [-1.0, 0.0]) > 0.5  # it drives
