"""The gaze stabiliser with real sensors (issue 15): the gyro's bias estimated from a still
robot's samples (the sim's own gyro model), not from a moving one, and taken off the VOR."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from services.gaze.sensing import GyroBias, predicted
from services.sim.sensors import ImuModel, SensorSpec

DT = 1e-3


def test_the_bias_of_a_still_gyro_is_found_within_a_hundredth_of_a_degree_per_second():
    """2 s still at 1 kHz: the model's gyro (0.005 °/s/√Hz, a bias of 0.1 °/s σ) averages to
    its bias within 0.01 °/s (the mean of 2000 samples of σ 0.16 °/s: 0.0035 °/s σ), a tenth
    of the bias itself."""
    for seed in range(5):
        imu = ImuModel(SensorSpec(), np.random.default_rng(seed))
        est = GyroBias()
        taken = 0
        for k in range(2000):
            gyro, _ = imu.measure(np.zeros(3), np.zeros(3), DT)
            taken += est.update(gyro, np.zeros(3), k * DT)
        assert taken >= 1990
        error = math.degrees(float(np.linalg.norm(est.bias - imu.bias)))
        assert error < 0.01, (seed, error, np.degrees(imu.bias))
        assert np.linalg.norm(imu.bias) > 5 * np.linalg.norm(est.bias - imu.bias)
        assert abs(est.still_s - taken * DT) < 0.01


def test_motion_is_not_taken_for_bias():
    """Neither a head the forward model says is turning, nor one the gyro alone says is
    turning (a push the model did not predict, 5 °/s), is taken for bias."""
    imu = ImuModel(replace(SensorSpec(), gyro_bias_walk=0.0), np.random.default_rng(0))
    est = GyroBias()
    for k in range(1000):  # 1 s still: the estimate
        est.update(imu.measure(np.zeros(3), np.zeros(3), DT)[0], np.zeros(3), k * DT)
    before = est.bias.copy()
    turning = np.array([0.0, 0.0, math.radians(20)])
    push = np.array([math.radians(5), 0.0, 0.0])
    taken = 0
    for k in range(1000, 3000):  # the model predicts a turn, then the gyro alone feels one
        truth, model = (turning, turning) if k < 2000 else (push, np.zeros(3))
        taken += est.update(imu.measure(truth, np.zeros(3), DT)[0], model, k * DT)
    assert taken == 0
    assert math.degrees(float(np.linalg.norm(est.bias - before))) < 0.005
    assert math.degrees(float(np.linalg.norm(est.bias - imu.bias))) < 0.015


def test_joints_are_carried_forward_over_their_latency():
    q = predicted({"neck_yaw": 0.1, "eye_tilt": -0.2}, {"neck_yaw": 2.0}, 0.005)
    assert q == {"neck_yaw": 0.1 + 0.01, "eye_tilt": -0.2}
    assert predicted({"neck_yaw": 0.1}, {"neck_yaw": 2.0}, 0.0) == {"neck_yaw": 0.1}
