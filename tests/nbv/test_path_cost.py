"""Path costs (Eq. 4.7-4.9) with OMPL's RRT-Connect against a floor map from voxel states."""

from __future__ import annotations

import math
from itertools import pairwise

import numpy as np
import pytest
from scipy import ndimage

from services.nbv.path_cost import FloorMap, PathPlanner, path_cost

VOXEL = 0.02
ORIGIN = np.array([-1.0, -2.0, 0.0])


def world(obstacles: list[tuple[float, float, float, float]]) -> FloorMap:
    """A 4 m × 4 m floor with box obstacles (x0, y0, x1, y1), 0.8 m high."""
    states = np.ones((200, 200, 60), np.uint8)
    xs = ORIGIN[0] + (np.arange(200) + 0.5) * VOXEL
    ys = ORIGIN[1] + (np.arange(200) + 0.5) * VOXEL
    for x0, y0, x1, y1 in obstacles:
        ix = (xs >= x0) & (xs < x1)
        iy = (ys >= y0) & (ys < y1)
        states[np.ix_(ix, iy, np.arange(5, 40))] = 2
    return FloorMap.from_states(states, ORIGIN, VOXEL)


def test_eq_4_8_takes_the_slower_of_translation_and_rotation():
    path = np.array([[0, 0, 0], [1, 0, 0], [1, 0, math.pi], [1, 1, -math.pi / 2]])
    # 1 m at 0.5 m/s = 2 s; π at 1 rad/s = π s; 1 m vs |Δα| = π/2 (wrapped): 2 s
    assert path_cost(path, 0.5, 1.0) == pytest.approx(2 + math.pi + 2)
    # Δα wraps (Eq. 4.7): from 179° to -179° is 2°, not 358°
    turn = np.array([[0, 0, math.radians(179)], [0, 0, math.radians(-179)]])
    assert path_cost(turn, 0.5, 1.0) == pytest.approx(math.radians(2))


def test_a_free_straight_line_costs_its_length():
    planner = PathPlanner(world([]), 0.45, 0.5, 1.0)
    cost, path = planner.cost((0.0, 0.0, 0.0), (2.0, 0.0, 0.0))
    assert len(path) == 2 and cost == pytest.approx(4.0)


def test_an_obstacle_between_robot_and_view_makes_the_path_longer_than_the_line():
    planner = PathPlanner(world([(0.8, -1.0, 1.2, 1.0)]), 0.45, 0.5, 1.0)  # a wall across
    start, goal = np.array([0.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    for _ in range(30):  # RRT is random: before the exact segment check 1 in 8 paths grazed it
        cost, path = planner.cost(start, goal)
        assert math.isfinite(cost) and cost > 4.0 + 0.5
        assert np.allclose(path[0], start) and np.allclose(path[-1], goal)
        # every waypoint and every segment between them keeps the footprint clear of the wall
        for a, b in pairwise(path):
            pts = a[:2] + np.linspace(0, 1, 2000)[:, None] * (b[:2] - a[:2])
            assert planner.valid(pts).all()


def test_the_segment_check_is_exact():
    """A segment is free iff every point on it is: 3,000 random segments against 20,000 samples
    each (a corner of an inflated obstacle cut by a few mm is caught)."""
    planner = PathPlanner(world([(0.8, -1.0, 1.2, 1.0), (-0.5, 1.0, 0.0, 1.3)]), 0.45, 0.5, 1.0)
    rng = np.random.default_rng(0)
    a, b = rng.uniform(-1, 3, (3000, 2)), rng.uniform(-2, 2, (3000, 2))
    t = np.linspace(0, 1, 20000)[:, None]
    dense = [planner.valid(p + t * (q - p)).all() for p, q in zip(a, b, strict=True)]
    exact = [planner._segment_free(p, q) for p, q in zip(a, b, strict=True)]
    assert 100 < sum(exact) < 2900  # both outcomes are exercised
    assert dense == exact


def test_unreachable_views_cost_infinity():
    # the goal inside an obstacle, and a goal inside a closed room
    room = [
        (1.5, -0.5, 2.8, -0.4),
        (1.5, 0.4, 2.8, 0.5),
        (1.5, -0.5, 1.6, 0.5),
        (2.7, -0.5, 2.8, 0.5),
    ]
    planner = PathPlanner(world([(0.8, -1.0, 1.2, 1.0), *room]), 0.2, 0.5, 1.0)
    assert planner.cost((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))[0] == math.inf
    assert planner.cost((0.0, 0.0, 0.0), (2.15, 0.0, 0.0))[0] == math.inf
    assert planner.cost((0.0, 0.0, 0.0), (0.0, 1.5, 0.0))[0] < math.inf


def test_the_robot_does_not_block_itself():
    states = np.ones((200, 200, 60), np.uint8)
    states[45:55, 95:105, 10:20] = 2  # the robot's own arm, seen by its camera, at (0, 0)
    free = FloorMap.from_states(states, ORIGIN, VOXEL, keep_free=[(0.0, 0.0, 0.55)])
    assert PathPlanner(free, 0.45, 0.5, 1.0).cost((0, 0, 0), (1.0, 0.0, 0.0))[0] == pytest.approx(
        2.0
    )


def test_outside_the_map_is_unknown_space_not_an_obstacle():
    planner = PathPlanner(world([(0.8, -1.0, 1.2, 1.0)]), 0.45, 0.5, 1.0)
    assert planner.floor.lookup(np.array([[-5.0, 0.0], [0.0, 9.0]])).tolist() == [np.inf] * 2
    # a start beside the map drives in along the straight line (it crosses no obstacle)
    cost, path = planner.cost((-2.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    assert len(path) == 2 and cost == pytest.approx(4.0)
    # a line through the wall is still refused, wherever it starts
    assert not planner._segment_free(np.array([-2.0, 0.0]), np.array([2.0, 0.0]))


def test_maybe_reachable_is_false_only_where_the_cost_is_infinite():
    """The planner's cheap filter (no search): a goal in an obstacle or in a closed room is
    refused at once; every goal it refuses costs ∞, and every goal with a path passes it."""
    room = [(1.5, -0.5, 2.8, -0.4), (1.5, 0.4, 2.8, 0.5), (1.5, -0.5, 1.6, 0.5),
            (2.7, -0.5, 2.8, 0.5)]  # fmt: skip
    planner = PathPlanner(world([(0.8, -1.0, 1.2, 1.0), *room]), 0.2, 0.5, 1.0)
    start = np.array([0.0, 0.0, 0.0])
    goals = np.column_stack([np.random.default_rng(1).uniform([-1, -2], [3, 2], (200, 2)),
                             np.zeros(200)])  # fmt: skip
    goals[:2] = [(1.0, 0.0, 0.0), (2.15, 0.0, 0.0)]  # in the wall, in the room
    maybe = planner.maybe_reachable(start, goals)
    assert not maybe[0] and not maybe[1]
    costs = np.array([planner.cost(start, g)[0] for g in goals])
    assert np.isinf(costs[~maybe]).all() and 20 < (~maybe).sum() < 180
    assert maybe[np.isfinite(costs)].all()


def test_the_floor_map_blocks_occupied_columns_and_unseen_ones_inside_the_roi():
    """Obstacles: a column with an occupied voxel between 5 cm and 2 m, and inside the roi's
    xy box a column unknown up to 1.3 m; the floor (below 5 cm) and the space above 2 m do not
    count, nor do unseen columns outside the box. Clearance = distance to the nearest one."""
    rng = np.random.default_rng(11)
    states = rng.choice([0, 1], p=[0.3, 0.7], size=(60, 50, 120)).astype(np.uint8)
    states[:, :, :2] = 2  # the floor
    states[:, :, 101:] = 2  # above 2 m
    states[:20, :20, 2:66] = 0  # never seen up to 1.3 m (k 2..65): 10 × 10 inside the roi
    posts = rng.integers(0, [60, 50], (6, 2))
    states[posts[:, 0], posts[:, 1], 50] = 2
    roi = (np.array([-1.0, -2.0, 0.5]), np.array([-0.8, -1.8, 1.0]))  # cells x, y < 10
    floor = FloorMap.from_states(states, ORIGIN, VOXEL, unseen_inside=roi)
    obstacle = np.any(states[:, :, 2:100] == 2, axis=2)
    unseen = np.all(states[:, :, 2:65] == 0, axis=2)
    obstacle[:10, :10] |= unseen[:10, :10]
    assert obstacle[:10, :10].all() and not obstacle[10:20, 10:20].any()
    assert obstacle.sum() == 100 + len({tuple(p) for p in posts if not (p < 10).all()})
    expected = ndimage.distance_transform_edt(~obstacle) * VOXEL
    assert np.allclose(floor.clearance, expected)


@pytest.mark.parametrize("nz", [37, 48])  # columns that start anywhere in a word, and on one
def test_the_floor_columns_are_numpys_any_and_all_of_their_layers(nz):
    """Obstacle: an occupied voxel in the layers [k0, k1); unseen: the layers [k0, kh) all
    unknown; told eight voxels at a time, with the bytes before the first and after the last
    whole word one by one: as numpy's ``any`` / ``all`` over the same layers, on a random
    map with a lone occupied voxel at every layer of the range's ends and empty columns."""
    rng = np.random.default_rng(5)
    states = rng.choice([0, 1, 2], p=[0.7, 0.28, 0.02], size=(23, 19, nz)).astype(np.uint8)
    states[:5] = 0  # unknown columns
    k0, k1, kh = 7, 29, 31
    for i, k in enumerate([k0 - 1, k0, k1 - 1, k1, kh - 1, kh]):
        states[i, 10, :] = 0
        states[i, 10, k] = 2  # a column unknown but for one occupied voxel, at layer k
    origin = np.array([0.0, 0.0, 0.0])
    floor = FloorMap.from_states(
        states, origin, VOXEL, z_range=(k0 * VOXEL, k1 * VOXEL), unseen_inside=(origin, [1, 1]),
        unseen_height=kh * VOXEL,
    )  # fmt: skip
    obstacle = (states[:, :, k0:k1] == 2).any(axis=2) | (states[:, :, k0:kh] == 0).all(axis=2)
    assert obstacle.any() and not obstacle.all()
    assert np.array_equal(floor.clearance == 0, obstacle)
