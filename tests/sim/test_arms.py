"""ARMAR-III's arms: pinocchio's kinematics against MuJoCo's, the visual servo's convergence,
the arm command contract, and a cup grasped while the platform drives past it lifts with the
hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from experiments.servo import GraspServo, ServoConfig, grasp_rotation, project
from schemas import ArmCommand
from services.common.arm import ArmKinematics, arm_spec, rotation_error
from services.sim.robots import ARMAR3
from services.sim.sensors import planar
from services.sim.world import World


@pytest.fixture(scope="module")
def left() -> ArmKinematics:
    return ArmKinematics("armar3", "left")


@pytest.mark.parametrize("side", ["left", "right"])
def test_forward_kinematics_matches_mujoco(side: str) -> None:
    """The grasp frame from pinocchio (the robot's MJCF) equals MuJoCo's site, for random arm
    and hip configurations and platform poses."""
    world = World("grasping", ARMAR3)
    kin = ArmKinematics("armar3", side)
    site = world.model.site(f"robot/{kin.spec.grasp_site}").id
    rng = np.random.default_rng(1)
    for _ in range(10):
        base = (rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(-3, 3))
        q_arm = rng.uniform(kin.lower, kin.upper)
        arm = dict(zip(kin.spec.joints, q_arm, strict=True))
        world.place(base=base, hip_yaw=rng.uniform(-1, 1), **arm)
        names, q, _ = world.joint_state()
        T = kin.pose(dict(zip(names, q, strict=True)), base)
        assert np.abs(T[:3, 3] - world.data.site_xpos[site]).max() < 1e-9
        assert np.abs(T[:3, :3] - world.data.site_xmat[site].reshape(3, 3)).max() < 1e-9


def test_jacobian_against_finite_differences(left: ArmKinematics) -> None:
    q = dict(ARMAR3.home)
    T, J = left.jacobian(q)
    for i, n in enumerate(left.spec.joints):
        q2 = dict(q, **{n: q.get(n, 0.0) + 1e-6})
        T2 = left.pose(q2)
        assert np.allclose((T2[:3, 3] - T[:3, 3]) / 1e-6, J[:3, i], atol=1e-5)
        assert np.allclose(rotation_error(T2[:3, :3], T[:3, :3]) / 1e-6, J[3:, i], atol=1e-5)


def test_no_arms_named() -> None:
    with pytest.raises(KeyError, match="armar6 has no left arm"):
        arm_spec("armar6", "left")


def test_projection_carries_the_object_to_the_reach() -> None:
    """An object ahead, the platform driving towards it at 0.1 m/s: projected to the reach's
    front edge along its relative motion; inside the reach: itself."""
    p, inside = project(np.array([1.2, 0.5, 0.9]), np.array([-0.1, 0.0, 0.0]), (0.05, 0.45))
    assert not inside and np.allclose(p, [0.45, 0.5, 0.9])
    p, inside = project(np.array([0.3, 0.5, 0.9]), np.array([-0.1, 0.0, 0.0]), (0.05, 0.45))
    assert inside and np.allclose(p, [0.3, 0.5, 0.9])


def _run_servo(world, kin, servo, cup_base, seconds, offset=None):
    offset = np.zeros(3) if offset is None else offset
    for _ in range(int(seconds * 100)):
        names, q, _ = world.joint_state()
        s = servo.step(world.time, dict(zip(names, q, strict=True)), offset, cup_base, np.zeros(3))
        world.command_joints(list(kin.spec.joints), "velocity", s.velocity)
        world.step(10)
    return s


def test_servo_converges_on_a_static_cup_from_random_starts(left: ArmKinematics) -> None:
    """Ten random starts (each arm joint up to 0.8 rad from rest) and cups across the reach:
    the PBVS law (λ = 3/s) brings the grasp frame to the grasp pose within 4 s, under 5 mm
    and 3°. (A servo is a local controller: from anywhere in the joint ranges, an arm folded
    against two limits at once stays there.)"""
    world = World("grasping", ARMAR3)
    config = ServoConfig(tolerance=(0.0, 0.0))  # never closing: only the pose is driven
    R = grasp_rotation(config.approach_tilt)
    rest = left.arm_q(ARMAR3.home)
    rng = np.random.default_rng(7)
    for trial in range(10):
        cup = np.array([rng.uniform(0.1, 0.4), rng.uniform(0.5, 0.56), 0.9])
        start = np.clip(rest + rng.uniform(-0.8, 0.8, 7), left.lower, left.upper)
        world.place(base=(0.0, -2.0, 0.0), **dict(zip(left.spec.joints, start, strict=True)))
        servo = GraspServo(left, config)
        servo.phase = "grasp"  # straight to the grasp pose (no fingers: the cup is far away)
        _run_servo(world, left, servo, cup, 4.0)
        names, q, _ = world.joint_state()
        T = left.pose(dict(zip(names, q, strict=True)))
        e_p = np.linalg.norm(T[:3, 3] - (cup + config.grasp_offset))
        e_r = math.degrees(np.linalg.norm(rotation_error(R, T[:3, :3])))
        assert e_p < 0.005 and e_r < 3.0, (trial, e_p, e_r)


def test_servo_corrects_the_kinematics_by_the_seen_hand(left: ArmKinematics) -> None:
    """The kinematics say the hand is 2 cm off where the cameras see it: the servo puts the
    real hand on the grasp pose, not the modelled one."""
    world = World("grasping", ARMAR3)
    cup = np.array([0.25, 0.53, 0.9])
    world.place(base=(0.0, -2.0, 0.0))
    servo = GraspServo(left, ServoConfig(tolerance=(0.0, 0.0)))
    servo.phase = "grasp"
    offset = np.array([0.02, -0.01, 0.0])
    _run_servo(world, left, servo, cup, 4.0, offset)
    names, q, _ = world.joint_state()
    T = left.pose(dict(zip(names, q, strict=True)))
    assert np.linalg.norm(T[:3, 3] + offset - (cup + servo.config.grasp_offset)) < 0.005


def test_cartesian_arm_command() -> None:
    """cmd/arm in cartesian mode: the robot's IK resolves the goal; the hand arrives within
    5 mm."""
    world = World("grasping", ARMAR3)
    world.place(base=(0.0, -2.0, 0.0))
    goal = np.eye(4)
    goal[:3, :3] = grasp_rotation(math.radians(20))
    goal[:3, 3] = (0.25, 0.53, 0.95)
    cmd = ArmCommand(arm="left", mode="cartesian", goal=goal, gripper=0.5)
    world.command_arm(cmd.arm, cmd.mode, cmd.names, cmd.values, cmd.goal, cmd.gripper)
    world.step(3000)
    names, q, _ = world.joint_state()
    state = dict(zip(names, q, strict=True))
    T = ArmKinematics("armar3", "left").pose(state)
    assert np.linalg.norm(T[:3, 3] - goal[:3, 3]) < 0.005
    assert abs(state["l_finger_a"] - 0.0325) < 0.002
    assert world.command_arm("left", "velocity", ["neck_yaw"], np.array([0.1])) == ["neck_yaw"]
    with pytest.raises(KeyError):
        ArmKinematics("armar6", "left")


def test_cup_grasped_while_driving_past_lifts_with_the_hand(left: ArmKinematics) -> None:
    """The platform drives past the table at 0.1 m/s; the servo, on the cup's true position,
    waits at the projected pose, moves in once the cup is in reach, closes and lifts: the cup
    comes up with the hand (≥ 6 cm) and stays in it."""
    robot = dataclasses.replace(ARMAR3, vel_lin=0.1)
    world = World("grasping", robot)
    cup = world.model.body("cup").id
    z0 = float(world.data.xpos[cup][2])
    servo = GraspServo(left)
    world.place(base=(1.0, 0.0, 0.0))  # on the line past the table (y = 0), facing along it
    world.set_base_goal(5.0, 0.0, 0.0)
    phases = []
    while world.time < 30.0 and servo.phase != "done":
        x, y, yaw, vx, vy, _ = world.base_pose()
        Tb = planar(x, y, yaw)
        names, q, _ = world.joint_state()
        p = (np.linalg.inv(Tb) @ np.array([*world.data.xpos[cup], 1.0]))[:3]
        s = servo.step(
            world.time, dict(zip(names, q, strict=True)), np.zeros(3), p,
            -(Tb[:3, :3].T @ np.array([vx, vy, 0.0])),
        )  # fmt: skip
        if not phases or phases[-1] != s.phase:
            phases.append(s.phase)
        world.command_arm("left", "velocity", list(left.spec.joints), s.velocity, None, s.gripper)
        world.step(10)
    assert phases == ["approach", "grasp", "close", "lift", "done"]
    names, q, _ = world.joint_state()
    hand = left.pose(dict(zip(names, q, strict=True)), world.base_pose()[:3])[:3, 3]
    assert world.data.xpos[cup][2] - z0 > 0.06
    assert np.linalg.norm(world.data.xpos[cup] - hand) < 0.04
