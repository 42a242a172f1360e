"""The robot never perceives itself: its arm held up in front of its camera is masked by its
kinematics (the MJCF posed by the joints the frame carries) before primitives are fitted."""

from __future__ import annotations

import numpy as np
import pytest

from schemas import CameraIntrinsics
from services.common.robots import robot_mjcf
from services.perception.pipeline import Perception, PerceptionConfig
from services.perception.self_mask import RobotBody
from services.sim import capture
from services.sim.render import CameraRenderer, intrinsics
from services.sim.robots import ARMAR3
from services.sim.world import World

CAMERA = "left_peripheral"


@pytest.fixture(scope="module")
def arm_in_view():
    """ARMAR-III away from the table, its left arm raised, the camera looking at its hand:
    (depth, rgb, intrinsics, camera pose, joints, the robot's pixels by MuJoCo's segmentation,
    the hand's position)."""
    world = World("grasping", ARMAR3)
    world.place(base=(0.0, -2.0, 0.0), l_shoulder_pitch=-1.2, l_elbow=-0.9, l_shoulder_roll=0.1)
    hand = world.data.xpos[world.model.body("robot/l_hand").id].copy()
    assert world.look_at(hand, CAMERA) < 1e-3
    renderer = CameraRenderer(world.model, 640, 480)
    renderer.snapshot(world.data, world.cameras[CAMERA])
    rgb, depth = renderer.render(depth=True)
    seg = renderer.segmentation(world.data, world.cameras[CAMERA])
    renderer.close()
    mine = np.array([world.model.body(int(b)).name.startswith("robot/")
                     for b in world.model.geom_bodyid])  # fmt: skip
    robot_px = (seg >= 0) & mine[np.maximum(seg, 0)]
    names, q, _ = world.joint_state()
    K = intrinsics(world.model, world.cameras[CAMERA], 640, 480)
    return (
        depth,
        rgb,
        K,
        world.T_world_camera(CAMERA),
        dict(zip(names, q, strict=True)),
        robot_px,
        hand,
    )


def test_mask_is_the_robots_pixels(arm_in_view) -> None:
    """The mask from the kinematics equals the robot's pixels in MuJoCo's segmentation: every
    arm pixel masked, and scene pixels only within the 2 cm margin (IoU ≥ 0.95)."""
    depth, _, K, _, joints, robot_px, _ = arm_in_view
    assert robot_px.sum() > 10_000  # the arm fills a good part of the image
    mask = RobotBody(robot_mjcf("armar3")).mask(depth, K.fx, K.fy, K.cx, K.cy, CAMERA, joints)
    assert (robot_px & ~mask).sum() <= 0.002 * robot_px.sum()
    assert (mask & robot_px).sum() / (mask | robot_px).sum() >= 0.95
    # at the rest pose the arm is out of sight: nothing is masked
    rest = {**joints, "l_shoulder_pitch": -0.3, "l_elbow": -1.3, "l_shoulder_roll": 0.15}
    far = np.where(robot_px, np.float32(3.0), depth)  # the arm's pixels as if it were not there
    assert not RobotBody(robot_mjcf("armar3")).mask(far, K.fx, K.fy, K.cx, K.cy, CAMERA, rest).any()


def test_perception_leaves_the_arm_out(arm_in_view) -> None:
    """Without the mask, primitives are fitted on the arm (their inliers around the hand);
    with it, none: every primitive is scene (its inliers' centre over 0.3 m from the hand)."""
    depth, rgb, K, T, joints, _, hand = arm_in_view
    perception = Perception(PerceptionConfig(depth_min=0.1, depth_max=4.0))
    K_ = CameraIntrinsics(width=640, height=480, fx=K.fx, fy=K.fy, cx=K.cx, cy=K.cy)

    def near_hand(result) -> list[float]:
        """Distances to the hand of the primitives whose inliers lie around it."""
        d = [float(np.linalg.norm(p.points.mean(axis=0) - hand)) for p in result.primitives]
        return [x for x in d if x < 0.3]

    blind = perception.perceive(depth, rgb, K_, T)
    assert near_hand(blind), "the unmasked arm should show up as primitives"
    mask = RobotBody(robot_mjcf("armar3")).mask(depth, K.fx, K.fy, K.cx, K.cy, CAMERA, joints)
    seeing = perception.perceive(depth, rgb, K_, T, mask)
    assert near_hand(seeing) == []
    assert len(seeing.primitives) >= 2  # the floor and the table are still there


def test_sim_frames_carry_their_joints() -> None:
    world = World("grasping", ARMAR3)
    world.place(l_elbow=-0.7)
    renderer = CameraRenderer(world.model, 64, 48)
    T, stamp = capture.snapshot(world, renderer, CAMERA)
    frame = capture.frame(world, renderer, CAMERA, T, stamp, 0, None)
    renderer.close()
    joints = dict(zip(frame.joint_names, frame.joint_positions, strict=True))
    assert joints["l_elbow"] == pytest.approx(-0.7) and "l_finger_a" in joints
