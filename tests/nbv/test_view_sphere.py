"""The view sphere (Eq. 4.1-4.4), its sampling, and the head IK that reaches a view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.common.robots import robot_mjcf
from services.nbv import view_sphere as vs
from services.nbv.kinematics import HeadIK

CENTRE = np.array([1.0, 2.0, 0.8])


@pytest.mark.parametrize(
    ("t", "expected"),
    [
        ((1.2, 0.0, 0.9), (2.2, 2.0, math.pi)),  # east of the centre: faces west
        ((0.0, 1.2, 0.9), (1.0, 3.2, -math.pi / 2)),  # north: faces south
        ((-0.6, -0.6, 1.2), (0.4, 1.4, math.pi / 4)),  # south-west: faces north-east
        ((0.0, -1.5, 0.0), (1.0, 0.5, math.pi / 2)),
    ],
)
def test_platform_pose_eq_4_2_and_4_3(t, expected):
    x, y, yaw = vs.platform_pose(CENTRE, np.array(t))
    assert (x, y) == pytest.approx(expected[:2])
    assert vs.wrap(yaw - expected[2]) == pytest.approx(0.0, abs=1e-12)


def test_views_look_at_the_centre_without_roll():
    for t in vs.equidistant(12):
        T = vs.view_pose(CENTRE, t)
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
        to_centre = (CENTRE - T[:3, 3]) / np.linalg.norm(CENTRE - T[:3, 3])
        assert R[:, 2] @ to_centre == pytest.approx(1.0)  # optical axis through the centre
        assert R[2, 0] == pytest.approx(0.0, abs=1e-12)  # image x level: no roll
        assert R[2, 1] < 0  # image y points down
        assert np.linalg.norm(t) == pytest.approx(1.5)


def test_equidistant_grid_is_the_upper_half_in_steps_of_2pi_over_k():
    k = 12
    t = vs.equidistant(k)
    assert np.all(t[:, 2] > 0)
    theta = np.degrees(np.arccos(t[:, 2] / 1.5))
    phi = np.degrees(np.mod(np.arctan2(t[:, 1], t[:, 0]), 2 * math.pi))
    assert np.allclose(np.mod(theta + 1e-6, 30), 0, atol=1e-4)
    assert sorted(set(np.round(theta, 6))) == [30, 60]
    assert len(t) == 2 * k and np.allclose(np.mod(phi + 1e-6, 30), 0, atol=1e-4)


def test_random_sampling_is_uniform_on_the_sphere():
    rng = np.random.default_rng(0)
    t = vs.random(10_000, rng, upper=False)
    assert np.allclose(np.linalg.norm(t, axis=1), 1.5)
    assert np.linalg.norm(t.mean(axis=0)) < 0.05  # mean direction ≈ 0 (1.5 m radius)
    # uniform: every octant holds an eighth, z is uniform on [-r, r] (Archimedes)
    octant = (t[:, 0] > 0) * 4 + (t[:, 1] > 0) * 2 + (t[:, 2] > 0)
    assert np.allclose(np.bincount(octant, minlength=8) / len(t), 1 / 8, atol=0.015)
    hist, _ = np.histogram(t[:, 2], bins=10, range=(-1.5, 1.5))
    assert np.allclose(hist / len(t), 0.1, atol=0.015)
    upper = vs.random(10_000, rng)
    assert np.all(upper[:, 2] >= 0) and upper[:, 2].mean() == pytest.approx(0.75, abs=0.03)


def test_head_ik_reaches_a_view_or_says_it_cannot():
    ik = HeadIK(robot_mjcf("armar6"), "head_rgbd", "armar6")
    lo, hi = ik.height_range()
    assert 1.1 < lo < hi < 1.8
    theta = math.radians(62)
    t = vs.spherical(1.5, [theta], [math.pi])[0]
    base = vs.platform_pose(CENTRE, t)
    sol = ik.solve(base, CENTRE, CENTRE[2] + t[2])
    assert sol is not None
    T = sol.T_world_camera
    assert T[2, 3] == pytest.approx(CENTRE[2] + t[2], abs=0.005)
    d = (CENTRE - T[:3, 3]) / np.linalg.norm(CENTRE - T[:3, 3])
    assert math.degrees(math.acos(min(1.0, T[:3, 2] @ d))) < 0.5
    for name, value in sol.joints.items():
        j = ik.names.index(name)
        assert ik.lo[j] - 1e-9 <= value <= ik.hi[j] + 1e-9
    # a view from straight above the centre needs a camera at 2.3 m: no torso reaches it
    top = np.array([1e-3, 0.0, 1.5])
    assert ik.solve(vs.platform_pose(CENTRE, top), CENTRE, CENTRE[2] + 1.5) is None


def test_compiled_head_ik_solves_as_pinocchio_does():
    """The compiled solver (the camera's chain out of the model) against the same Gauss-Newton
    through pinocchio's forward kinematics, on every view of a 5° sphere: the same views
    reached, the same joints and camera poses to rounding."""
    ik = HeadIK(robot_mjcf("armar6"), "head_rgbd", "armar6")
    assert ik.chain is not None
    t = vs.equidistant(72, 1.5)[::3]
    bases = [vs.platform_pose(CENTRE, ti) for ti in t]
    heights = CENTRE[2] + t[:, 2]
    fast = ik.solve_many(bases, np.tile(CENTRE, (len(t), 1)), heights)
    ref = [ik.solve_pinocchio(b, CENTRE, h) for b, h in zip(bases, heights, strict=True)]
    assert [s is None for s in fast] == [s is None for s in ref]
    assert sum(s is not None for s in fast) > 20
    for a, b in zip(fast, ref, strict=True):
        if a is not None:
            assert np.allclose(list(a.joints.values()), list(b.joints.values()), atol=1e-9)
            assert np.allclose(a.T_world_camera, b.T_world_camera, atol=1e-9)
            # acos near 1 turns a rounding of 1e-16 into 1.5e-8 rad
            assert a.aim_error == pytest.approx(b.aim_error, abs=1e-6)


def test_compiled_lines_of_sight_match_the_numpy_one():
    """The planner's visibility check of all views at once gives line_of_sight's answers."""
    from services.nbv import topdown

    rng = np.random.default_rng(3)
    states = rng.choice(np.array([0, 1, 2], np.uint8), size=(40, 30, 20), p=[0.3, 0.67, 0.03])
    origin = np.array([-0.2, -0.1, 0.0])
    a = rng.uniform(-0.3, 0.8, (400, 3))
    b = rng.uniform(-0.3, 0.8, (400, 3))
    ref = [
        topdown.line_of_sight(states, origin, 0.02, p, q, 0.15) for p, q in zip(a, b, strict=True)
    ]
    got = topdown.lines_of_sight(states, origin, 0.02, a, b, 0.15)
    assert 0 < sum(ref) < len(ref)
    assert got.tolist() == ref
