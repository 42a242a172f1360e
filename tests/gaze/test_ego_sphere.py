"""The ego-sphere (5.1) and its saliency sources (5.1.1): uniformity, expiry, pruning,
winner-takes-all with inhibition of return, the Kalman belief's saliency, colour blobs."""

from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

from services.common.robots import robot_mjcf
from services.gaze.ego_sphere import EgoSphere
from services.gaze.kinematics import GazeKinematics
from services.gaze.saliency import ObjectBelief, colour_blobs, entropy, pixel_rays

AHEAD, LEFT, BEHIND = np.array([1.0, 0, -0.3]), np.array([0.3, 1.0, -0.2]), np.array([-1.0, 0, 0])


@pytest.fixture(scope="module")
def sphere() -> EgoSphere:
    return EgoSphere()


def test_40000_points_near_uniform(sphere):
    assert len(sphere) == 40_000
    assert np.allclose(np.linalg.norm(sphere.points, axis=1), 1.0)
    nn = sphere.tree.query(sphere.points, k=2)[0][:, 1]
    median = np.median(nn)
    assert nn.min() > 0.9 * median and nn.max() < 1.1 * median, (nn.min(), nn.max(), median)
    assert np.abs(sphere.points.mean(0)).max() < 1e-3  # no side favoured


def test_eq_5_1_weighted_sources_and_expiry_after_5_s():
    ego = EgoSphere(noise=0.0)
    j = ego.tree.query(AHEAD / np.linalg.norm(AHEAD))[1]
    ego.add("object", ego.points[j], 1.0, stamp=0.0, weight=3.0)
    ego.add("blob", ego.points[j], 0.2, stamp=2.0, weight=1.0)
    assert ego.saliency(4.0)[j] == pytest.approx((3 * 1.0 + 1 * 0.2) / 4, rel=1e-3)
    assert ego.saliency(5.5)[j] == pytest.approx(0.2 / 4, rel=1e-3)  # the object's is > 5 s old
    assert ego.saliency(7.5)[j] == 0.0


def test_an_unreachable_point_is_never_chosen():
    kin = GazeKinematics(robot_mjcf("armar3"), ["left_foveal"])
    joints = ("neck_lower_pitch", "neck_yaw", "neck_upper_pitch", "eye_tilt", "eye_pan_left")
    ego = EgoSphere()
    ego.prune(kin.reachable_directions("left_foveal", joints, 5000), resolution_deg=4.0)
    assert 0.3 < ego.reachable.mean() < 0.7  # armar3 looks about ±90° around, not behind
    assert ego.reachable[ego.tree.query(AHEAD / np.linalg.norm(AHEAD))[1]]
    assert not ego.reachable[ego.tree.query(BEHIND)[1]]
    ego.add("manual", BEHIND, 10.0, stamp=0.0)
    ego.add("object", AHEAD, 1.0, stamp=0.0)
    winner = ego.select(1.0)
    assert ego.points[winner] @ (AHEAD / np.linalg.norm(AHEAD)) > np.cos(np.radians(5))
    ego.sources["object"].values[:] = 0  # only the unreachable one left: noise decides, inside
    for t in np.linspace(1, 4, 10):
        assert ego.reachable[ego.select(t)]


def test_inhibition_of_return_moves_the_winner_on_and_wears_off():
    ego = EgoSphere(noise=0.0, inhibition_deg=8.0, inhibition_s=3.0)
    ego.add("object", AHEAD, 1.0, stamp=0.0)
    ego.add("object", LEFT, 0.6, stamp=0.0)
    first = ego.select(0.5)
    assert ego.points[first] @ (AHEAD / np.linalg.norm(AHEAD)) > np.cos(np.radians(2))
    ego.inhibit(first, 0.5)
    second = ego.select(1.0)
    assert ego.points[second] @ (LEFT / np.linalg.norm(LEFT)) > np.cos(np.radians(2))
    assert ego.select(3.6) == first  # 3 s later the first may win again


def test_an_inhibited_object_leaves_no_tail_to_circle_and_noise_calls_no_saccade():
    """One salient object: once it is fixated and inhibited, its own spread (a Gaussian of 3°
    out to 9°) cannot win in its place, which held the gaze circling 5° off the box in the
    gaze node's test; with a floor above the noise nothing wins (the gaze stays)."""
    ego = EgoSphere(noise=1e-3)
    ego.add("object", AHEAD, 1.0, stamp=0.0)
    first = ego.select(0.5, floor=1e-2)
    assert ego.points[first] @ (AHEAD / np.linalg.norm(AHEAD)) > np.cos(np.radians(2))
    ego.inhibit(first, 0.5)
    s = ego.saliency(1.0)
    s[ego.inhibited_until > 1.0] = 0.0
    assert s.max() < 2e-3  # only noise left outside the inhibited disk
    assert ego.select(1.0, floor=1e-2) == -1
    narrow = EgoSphere(noise=1e-3, inhibition_deg=8.0)  # a disk narrower than the spread
    narrow.add("object", AHEAD, 1.0, stamp=0.0)
    narrow.inhibit(narrow.select(0.5), 0.5)
    assert narrow.select(1.0, floor=1e-2) >= 0  # the tail wins: what the default prevents


def test_kalman_fusion_shrinks_sigma_until_the_task_acuity_makes_saliency_zero():
    rng = np.random.default_rng(0)
    truth = np.array([1.5, 0.15, 0.86])
    R = np.diag([0.03, 0.03, 0.05]) ** 2  # one localisation result's covariance
    belief = ObjectBelief.first(truth + rng.normal(0, 0.03, 3), R, stamp=0.0, acuity=0.01)
    sigmas, saliencies = [belief.sigma], [belief.saliency]
    for k in range(1, 30):
        belief.update(truth + rng.multivariate_normal(np.zeros(3), R), R, stamp=0.05 * k)
        sigmas.append(belief.sigma)
        saliencies.append(belief.saliency)
    assert all(b < a for a, b in pairwise(sigmas))
    assert saliencies[0] == pytest.approx(entropy(sigmas[0]) - entropy(0.01))  # Eq. 5.2-5.4
    assert saliencies[0] > 2.0
    below = [s for s, sig in zip(saliencies, sigmas, strict=True) if sig < 0.01]
    assert below and all(s == 0.0 for s in below)
    assert np.linalg.norm(belief.mean - truth) < 0.02
    belief.predict(belief.stamp + 600.0)  # not looked at for ten minutes: salient again
    assert belief.saliency > 0


def test_a_green_cup_is_one_colour_blob_at_its_centre():
    img = np.full((240, 320, 3), 128, np.uint8)
    v, u = np.mgrid[:240, :320]
    img[(u - 200.0) ** 2 + (v - 80.0) ** 2 < 20**2] = (25, 180, 40)
    img[100:140, 20:60] = (200, 30, 30)
    for step, tol in ((1, 0.1), (2, 0.6)):  # every pixel, every 2nd (the default)
        blobs = sorted(colour_blobs(img, step=step), key=lambda b: -b[0])  # the cup on the right
        assert len(blobs) == 2
        (u0, v0, n0), (u1, v1, n1) = blobs
        assert abs(u0 - 200) < tol and abs(v0 - 80) < tol and 1200 < n0 < 1300
        assert abs(u1 - 39.5) < tol and abs(v1 - 119.5) < tol and n1 == 1600
    # a cluttered view keeps only the largest few
    for k in range(20):
        img[200:210, 10 + 15 * k : 20 + 15 * k] = (30, 30, 200)
    assert [n for *_, n in colour_blobs(img, most=3)] == [1600, 1264, 100]


def test_a_blob_pixel_gives_its_ray_in_the_world():
    T = np.eye(4)
    T[:3, :3] = [[0, 0, 1], [-1, 0, 0], [0, -1, 0]]  # optical z along world x, image x = −y
    K = (300.0, 300.0, 160.0, 120.0)
    rays = pixel_rays(np.array([[160.0, 120.0], [460.0, 120.0]]), K, T)
    assert np.allclose(rays[0], [1, 0, 0])
    assert np.allclose(rays[1], np.array([1, -1, 0]) / np.sqrt(2))  # 45° to the right
