"""The correction filter (``services/scene_memory/correction_filter.py``): odometry and view
registration weighed by their errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.adapters.dataset.drift import Drift
from services.adapters.dataset.formats import read
from services.adapters.dataset.frames import DatasetFrames
from services.adapters.dataset.gravity import level_frame
from services.common.poses import pose_difference
from services.scene_memory.config import SceneMemorySettings
from services.scene_memory.correction_filter import (
    CorrectionFilter,
    OdometryNoise,
    RegistrationNoise,
    _exp_rotation,
)
from services.scene_memory.node import new_memory
from tests.real import REAL, needs_real


def pose(x: float, y: float, yaw_deg: float, z: float = 1.2) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = _exp_rotation(np.array([0.0, 0.0, math.radians(yaw_deg)]))
    T[:3, 3] = (x, y, z)
    return T


def planar(x: float, y: float, yaw_deg: float) -> np.ndarray:
    return pose(x, y, yaw_deg, 0.0)


def drive(f: CorrectionFilter, steps: int, step_m: float, step_deg: float) -> np.ndarray:
    """Predict along an arc of ``steps`` odometry poses; the last one."""
    T = f.T_odom if f.T_odom is not None else pose(0, 0, 0)
    for _ in range(steps):
        T = T @ pose(step_m, 0, step_deg, 0.0)
        f.predict(T)
    return T


@pytest.mark.parametrize("dof", ["planar", "full"])
def test_after_a_long_drive_a_registration_is_taken_almost_whole(dof):
    """3 m and 90° of odometry (σ ≈ 7 cm and 2.4° by the 2 % model) against a registration's
    2 cm and 1°: a correction of 3 cm and 1° is taken to ≥ 85 %."""
    f = CorrectionFilter(dof)
    f.predict(pose(0, 0, 0))
    T_odom = drive(f, 30, 0.1, 3.0)
    measured = planar(0.03, 0.0, 1.0)
    f.update(measured)
    moved, turned = pose_difference(measured @ T_odom, f.T @ T_odom)
    assert moved < 0.15 * 0.03 + 0.003 and turned < 0.15, (moved, turned)


def test_after_a_few_centimetres_the_odometry_outweighs_a_registration():
    """5 cm of odometry (σ 1 mm) against a registration's σ of 2 cm: a 2 cm correction moves
    the state by less than 1 mm; with a registration trusted to 0.1 mm, by nearly all of it."""
    for sigma, most in ((0.02, 0.001), (0.0001, None)):
        f = CorrectionFilter("planar", registration=RegistrationNoise(sigma, sigma * 50))
        f.predict(pose(0, 0, 0))
        T_odom = drive(f, 1, 0.05, 0.0)
        f.update(planar(0.0, 0.02, 0.0))
        shift = float(np.linalg.norm((f.T @ T_odom)[:3, 3] - T_odom[:3, 3]))
        if most is not None:
            assert shift < most, shift
        else:
            assert shift > 0.019, shift


def test_the_covariance_is_carried_with_the_lever_arm_of_a_turn():
    """A yaw error σ about the old camera is, 1 m further along x, a sideways error of σ·1 m
    at the new camera, fully correlated with the yaw: as sampled turns about the old centre
    show."""
    sigma = math.radians(2.0)
    f = CorrectionFilter("planar", odometry=OdometryNoise(0, 0, 0, 0))
    f.predict(pose(0, 0, 0))
    f.P = np.diag([0.0, 0.0, sigma**2])
    f.predict(pose(1.0, 0.0, 0.0))
    rng = np.random.default_rng(0)
    shifts = []
    for theta in rng.normal(0, sigma, 4000):
        turn = np.eye(4)
        turn[:3, :3] = _exp_rotation(np.array([0, 0, theta]))  # about the old centre (origin)
        f_sample = CorrectionFilter("planar", odometry=OdometryNoise(0, 0, 0, 0))
        f_sample.T_odom = pose(1.0, 0.0, 0.0)
        shifts.append(f_sample.innovation(turn))
    sampled = np.cov(np.array(shifts).T)
    assert np.allclose(f.P, sampled, atol=0.1 * sigma**2), (f.P, sampled)
    assert f.P[1, 2] > 0.9 * sigma**2 and abs(f.P[0, 0]) < 1e-9


def test_noisy_registrations_average_out_and_the_drift_is_followed():
    """An odometry that drifts 1 % of the distance and 1 % of the turn along 200 steps of
    3.6 cm and 1.5° (redkitchen-a's pace), a registration every 3rd step off by σ = 2 cm and
    1°: the filtered correction's error (RMS over the steps) is under half the
    registration's own, and it follows the drift (its error stays well under the drift's).
    Taking each registration as it comes (R → 0) leaves the registration's error."""
    rng = np.random.default_rng(3)

    def run(noise: RegistrationNoise) -> tuple[float, float, float]:
        f = CorrectionFilter("planar", registration=noise)
        T_true = pose(0, 0, 0)
        T_odom = T_true.copy()
        f.predict(T_odom)
        errors, measured_errors, drift = [], [], []
        for k in range(1, 200):
            step = pose(0.036, 0.0, 1.5, 0.0)
            T_true = T_true @ step
            T_odom = T_odom @ pose(0.036 * 1.01, 0.0, 1.5 * 1.01, 0.0)
            f.predict(T_odom)
            truth = T_true @ np.linalg.inv(T_odom)  # the correction that is right
            if k % 3 == 0:
                noise_T = planar(*rng.normal(0, 0.02, 2), rng.normal(0, 1.0))
                measured = noise_T @ truth
                measured_errors.append(pose_difference(measured @ T_odom, T_true)[0])
                f.update(measured)
            errors.append(pose_difference(f.T @ T_odom, T_true)[0])
            drift.append(pose_difference(T_odom, T_true)[0])
        rms = float(np.sqrt(np.mean(np.square(errors))))
        return rms, float(np.sqrt(np.mean(np.square(measured_errors)))), float(np.mean(drift))

    filtered, measured, drift = run(RegistrationNoise(0.02, 1.0))
    assert filtered < 0.5 * measured, (filtered, measured)
    assert drift > 0.03 and filtered < 0.4 * drift, (filtered, drift)
    as_it_comes, measured, _ = run(RegistrationNoise(1e-5, 1e-4))
    assert as_it_comes > 0.8 * measured, (as_it_comes, measured)


def test_a_registration_the_odometry_cannot_explain_is_far_in_mahalanobis_distance():
    """After 10 cm of odometry (σ 2 mm), a registration 9 cm off is beyond χ² 99.9 %
    (d² > 16.3) of both errors; one of 1 cm is well within."""
    f = CorrectionFilter("planar")
    f.predict(pose(0, 0, 0))
    drive(f, 2, 0.05, 0.0)
    assert f.mahalanobis(planar(0.09, 0.0, 0.0)) > 16.27
    assert f.mahalanobis(planar(0.01, 0.0, 0.0)) < 1.0


def _held_errors(odometry_noise: float) -> np.ndarray:
    """redkitchen-a (a hand-held Kinect v1, 100 frames, 3.7 m and 175°) with the benchmark's
    drift (0.5 mm and 0.02° a frame), every frame integrated and registered every 0.5 s
    (planar) by the scene memory in this process: the error (m) of the pose it holds for
    each frame against the reference."""
    frames = DatasetFrames(read(REAL / "redkitchen-a"), drift=Drift(0.5, 0.02), colour=False)
    frames.T_up = level_frame(frames).T_up
    settings = SceneMemorySettings(registration=True, keyframe_move=0, keyframe_turn=0,
                                   odometry_noise=odometry_noise)  # fmt: skip
    memory = new_memory(settings)
    errors = []
    for seq, i in enumerate(frames.indices()):
        frame = frames.frame(i, seq)
        memory.integrate(frame)
        T = memory.T_world_odom if memory.T_world_odom is not None else np.eye(4)
        errors.append(pose_difference(frames.pose(i), T @ frame.T_world_camera)[0])
    return np.array(errors)


@needs_real
@pytest.mark.slow
def test_on_a_real_kinect_the_filter_keeps_registration_from_walking():
    """Taken as it comes, registration walks away from the reference (median ~42 mm over the
    frames, up to 90; measured 2026-12-06); weighed against a 2 % odometry, the held poses
    stay within half of that (median ~10 mm, at most ~24)."""
    weighed, as_it_comes = _held_errors(0.02), _held_errors(0.0)
    assert np.median(as_it_comes) > 0.025 and as_it_comes.max() > 0.06
    assert np.median(weighed) < 0.5 * np.median(as_it_comes), (weighed, as_it_comes)
    assert weighed.max() < 0.6 * as_it_comes.max()


def test_a_snapshot_keeps_the_filter():
    """A restarted memory restores the correction and its covariance (``state.dump``/``load``):
    the next update moves it exactly as it would have moved the one that kept running."""
    from services.scene_memory.state import dump, load

    f = CorrectionFilter("planar", OdometryNoise.share(0.03), RegistrationNoise(0.01, 0.5))
    f.predict(pose(0, 0, 0))
    drive(f, 5, 0.1, 4.0)
    f.update(planar(0.02, -0.01, 0.5))
    T_odom = drive(f, 3, 0.1, 2.0)
    restored, n = load(dump(f, 7))
    assert n == 7 and isinstance(restored, CorrectionFilter)
    assert restored.odometry == f.odometry and restored.motion == f.motion
    for g in (f, restored):
        g.predict(T_odom @ pose(0.05, 0, 1.0, 0.0))
        g.update(planar(0.03, 0.0, 0.8))
    assert np.allclose(restored.T, f.T) and np.allclose(restored.P, f.P)
