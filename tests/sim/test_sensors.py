"""The sensor models: each one's statistics match its parameters, measured the way one would
on a robot (a still robot's samples, a driven path against the truth)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.sim.robots import ARMAR6
from services.sim.sensors import (
    Delay,
    EncoderModel,
    ImuModel,
    Odometry,
    RobotSensors,
    SensorSpec,
)
from services.sim.world import World

SPEC = SensorSpec()
RATE = 1000.0


@pytest.fixture(scope="module")
def still() -> World:
    return World("tabletop_occluded", ARMAR6)


def test_gyro_and_accelerometer_noise_density_from_a_still_robot(still):
    """10 s of a still robot's IMU at 1 kHz: the white noise's σ per sample is density/√Δt
    (within 5 %), the gyro's mean is its bias (within 3σ of the mean's error), the stamps'
    jitter is the spec's."""
    model = ImuModel(SPEC, np.random.default_rng(1))
    gyro_true, acc_true, _ = still.imu()
    n, dt = 10_000, 1.0 / RATE
    gyro, acc, stamps = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    for k in range(n):
        gyro[k], acc[k] = model.measure(gyro_true, acc_true, dt)
        stamps[k] = model.stamp(k * dt)
    # first differences cancel the slow bias: var(Δ) = 2σ² (+ the bias step, 1e-6 of it)
    sigma_gyro = np.diff(gyro, axis=0).std(axis=0) / math.sqrt(2)
    density = sigma_gyro * math.sqrt(dt)
    assert np.allclose(density, SPEC.gyro_noise_density, rtol=0.05), (density, SPEC)
    sigma_acc = (acc - acc.mean(axis=0)).std(axis=0)
    assert np.allclose(sigma_acc * math.sqrt(dt), SPEC.accel_noise_density, rtol=0.05)
    # the bias shows as the mean of the still samples
    bias_error = np.abs(gyro.mean(axis=0) - gyro_true - model.bias)
    assert (bias_error < 3 * SPEC.gyro_noise_density / math.sqrt(n * dt) + 1e-5).all()
    jitter = stamps - np.arange(n) * dt
    assert jitter.std() == pytest.approx(SPEC.imu_stamp_jitter, rel=0.05)


def test_gyro_bias_starts_random_and_random_walks():
    """Across 400 robots the turn-on bias has the spec's σ (±15 %); over 60 s at 1 kHz its
    one-second steps have σ = walk·√1 s (±15 %)."""
    starts = np.array([ImuModel(SPEC, np.random.default_rng(s)).bias for s in range(400)])
    assert starts.std() == pytest.approx(SPEC.gyro_bias_sigma, rel=0.15)
    model = ImuModel(SPEC, np.random.default_rng(3))
    z = np.zeros(3)
    biases = []
    for k in range(60_000):
        model.measure(z, z, 1.0 / RATE)
        if k % 1000 == 999:
            biases.append(model.bias)
    steps = np.diff(np.array(biases), axis=0)
    assert steps.std() == pytest.approx(SPEC.gyro_bias_walk, rel=0.15)


def test_encoders_quantise_and_add_noise():
    """Positions fall on the encoder's grid; over positions spread across the grid the reading's
    error has σ = √(σ_noise² + res²/12) (±10 %) and no bias; velocities carry the velocity
    noise."""
    model = EncoderModel(SPEC, np.random.default_rng(4))
    rng = np.random.default_rng(5)
    q = rng.uniform(-1.0, 1.0, (5000, 3))
    readings = [model.measure(qk, np.zeros(3)) for qk in q]
    pos = np.array([r[0] for r in readings])
    vel = np.array([r[1] for r in readings])
    steps = pos / SPEC.encoder_resolution
    assert np.allclose(steps, np.round(steps), atol=1e-6)
    error = pos - q
    expected = math.sqrt(SPEC.encoder_noise**2 + SPEC.encoder_resolution**2 / 12)
    assert np.allclose(error.std(axis=0), expected, rtol=0.1), (error.std(axis=0), expected)
    assert np.abs(error.mean(axis=0)).max() < 4 * expected / math.sqrt(len(q))
    assert np.allclose(vel.std(axis=0), SPEC.encoder_velocity_noise, rtol=0.1)


def test_delay_line_releases_items_after_their_latency_in_order():
    d: Delay[int] = Delay(0.002)
    for k in range(5):
        d.push(k * 0.001, k)
    assert d.due(0.0015) == []
    assert d.due(0.003) == [0, 1]
    assert d.due(0.1) == [2, 3, 4]


def drive(world: World, odometry: Odometry, seconds: float, v=(0.0, 0.0, 0.0)) -> None:
    """Drive ``world`` at the platform-frame velocity ``v`` for ``seconds``, feeding the
    odometry every 5 ms (the state rate)."""
    world.set_base_velocity(*v, timeout=seconds)
    for _ in range(int(seconds * 200)):
        world.step(5)
        x, y, yaw, *_ = world.base_pose()
        odometry.update((x, y, yaw))


def test_odometry_drifts_with_distance_and_turn():
    """5 m driven straight: the believed position is off by the scale error times the distance
    (±30 %); a full turn in place: the believed heading is off by 1° (±30 %). The random walks
    are on, as on the robot."""
    world = World("corridor", ARMAR6)  # 10 m long, 2.9 m wide
    world.place((0.3, 0.0, 0.0))
    x, y, yaw, *_ = world.base_pose()
    odometry = Odometry(SPEC, np.random.default_rng(5), (x, y, yaw))
    drive(world, odometry, 10.4, (0.5, 0.0, 0.0))
    bx, by, _ = odometry.believed
    tx, ty, _ = odometry.true
    assert odometry.distance == pytest.approx(5.0, abs=0.15)
    error = math.hypot(bx - tx, by - ty)
    assert error == pytest.approx(SPEC.odometry_scale_error * odometry.distance, rel=0.3), error

    world = World("corridor", ARMAR6)
    world.place((0.3, 0.0, 0.0))
    x, y, yaw, *_ = world.base_pose()
    odometry = Odometry(SPEC, np.random.default_rng(6), (x, y, yaw))
    drive(world, odometry, 2 * math.pi + 0.5, (0.0, 0.0, 1.0))  # 0.5 s to reach 1 rad/s
    turned = odometry.turned
    assert turned == pytest.approx(2 * math.pi, rel=0.1)
    yaw_error = math.degrees(abs(math.remainder(odometry.believed[2] - odometry.true[2], math.tau)))
    assert yaw_error * 2 * math.pi / turned == pytest.approx(1.0, rel=0.3), yaw_error


def test_the_correction_maps_the_true_camera_pose_to_the_believed_one():
    """T_world_odom · T_true is the pose the odometry believes, for the platform itself and
    for anything on it (a camera 1 m ahead and 1.5 m up)."""
    sensors = RobotSensors(SPEC, 0, (1.0, 2.0, 0.3))
    sensors.odometry.update((3.0, 2.5, 1.1))
    from services.sim.sensors import planar

    T_true = planar(*sensors.odometry.true)
    T_believed = sensors.odometry.T_world_odom() @ T_true
    assert np.allclose(T_believed, planar(*sensors.odometry.believed), atol=1e-12)
    cam = np.eye(4)
    cam[:3, 3] = (1.0, 0.0, 1.5)
    moved = sensors.odometry.T_world_odom() @ (T_true @ cam)
    assert np.allclose(moved, planar(*sensors.odometry.believed) @ cam, atol=1e-12)
    assert np.linalg.norm(moved[:3, 3] - (T_true @ cam)[:3, 3]) > 0.01  # it did drift


def test_the_believed_camera_pose_is_the_kinematics_of_the_readings():
    """What a frame's camera pose is with the sensor models on (``SimNode.frame``): the
    forward kinematics of the encoders' readings with the platform where the odometry
    believes it is. After a 1.3 m drive with the head turned it is pinocchio's kinematics of
    those readings (to 1e-9), the odometry's drift (29 mm here) apart from the truth, and the
    encoders' error apart from the drifted true pose: turned by the readings' error on the
    two orthogonal neck axes, moved by at most the lift's error plus that angle times the
    15 cm from the neck to the camera. With the true platform and joints it is the true pose
    (1e-9)."""
    from services.common.poses import pose_difference
    from services.common.robots import robot_mjcf
    from services.gaze.kinematics import GazeKinematics

    world = World("tabletop_occluded", ARMAR6)
    sensors = RobotSensors(SPEC, 3, world.base_pose()[:3])
    head = {"torso_lift": 0.1, "neck_yaw": 0.3, "neck_pitch": -0.3}
    world.command_joints(list(head), "position", np.array(list(head.values())))
    world.set_base_goal(-1.0, 0.8, 0.6)
    for _ in range(2000):  # 10 s: there and at rest
        world.step(5)
        sensors.odometry.update(world.base_pose()[:3])
    assert world.base.status == "reached"
    names, q, qd = world.joint_state()
    truth = world.T_world_camera("head_rgbd")
    assert np.abs(world.T_world_camera_at("head_rgbd", world.base_pose()[:3], (names, q))
                  - truth).max() < 1e-9  # fmt: skip
    readings = sensors.encoders.measure(q, qd)[0]
    believed = world.T_world_camera_at("head_rgbd", sensors.odometry.believed, (names, readings))
    kin = GazeKinematics(robot_mjcf("armar6"), ["head_rgbd"])
    kin.update(kin.configuration(sensors.odometry.believed,
                                 dict(zip(names, readings, strict=True))))  # fmt: skip
    assert np.abs(kin.camera_pose("head_rgbd") - believed).max() < 1e-9

    # the odometry's error alone: the platform's (1.5 % of the distance and a random walk of
    # σ 5.7 mm here), and its heading's turning the camera's 7 cm lever
    drifted = sensors.odometry.T_world_odom() @ truth
    drift_m, _ = pose_difference(drifted, truth)
    distance = sensors.odometry.distance
    assert distance == pytest.approx(1.28, abs=0.05)
    (bx, by, byaw), (tx, ty, tyaw) = sensors.odometry.believed, sensors.odometry.true
    platform_m = math.hypot(bx - tx, by - ty)
    assert 0.2 < platform_m / (SPEC.odometry_scale_error * distance) < 2, platform_m
    lever = np.linalg.norm(truth[:2, 3] - (tx, ty))
    assert drift_m == pytest.approx(platform_m, abs=lever * abs(byaw - tyaw) + 1e-9)
    error = {n: readings[names.index(n)] - q[names.index(n)] for n in head}
    assert all(0 < abs(e) < SPEC.encoder_resolution / 2 + 5 * SPEC.encoder_noise
               for e in error.values()), error  # fmt: skip
    moved_m, turned_deg = pose_difference(believed, drifted)
    angle = math.hypot(error["neck_yaw"], error["neck_pitch"])
    assert math.radians(turned_deg) == pytest.approx(angle, rel=0.01)
    assert moved_m <= abs(error["torso_lift"]) + 0.15 * angle
    assert pose_difference(believed, truth)[0] == pytest.approx(drift_m, abs=1e-3)
