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
