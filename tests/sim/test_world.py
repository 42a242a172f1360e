"""The simulated robot: depth lands on the surfaces, the base reaches its goals within its
limits, head commands move the camera as the kinematics say, the IMU measures the head."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.sim import ground_truth, noise
from services.sim.render import CameraRenderer, intrinsics
from services.sim.robots import ARMAR3, ARMAR6
from services.sim.world import World, wrap


@pytest.fixture(scope="module")
def clutter() -> World:
    return World("tabletop_clutter", ARMAR6)


def _signed_distance(kind: str, size: np.ndarray, local: np.ndarray) -> np.ndarray:
    half = size / 2
    if kind == "box":
        return np.max(np.abs(local) - half, axis=1)
    if kind == "sphere":
        return np.linalg.norm(local, axis=1) - half[0]
    radial = np.hypot(local[:, 0], local[:, 1]) - half[0]
    return np.maximum(radial, np.abs(local[:, 2]) - half[2])


def test_depth_back_projects_onto_the_object_surfaces(clutter):
    w = clutter
    cam = w.cameras["head_rgbd"]
    r = CameraRenderer(w.model, 640, 480)
    try:
        r.snapshot(w.data, cam)
        _, depth = r.render()
        ids = r.segmentation(w.data, cam)
    finally:
        r.close()
    K = intrinsics(w.model, cam, 640, 480)
    labels, lookup = ground_truth.segmentation_labels(w)
    label = np.where(ids >= 0, lookup[np.maximum(ids, 0)], -1)
    v, u = np.mgrid[0:480, 0:640]
    xyz = np.stack([(u - K.cx) / K.fx * depth, (v - K.cy) / K.fy * depth, depth], -1)
    T = w.T_world_camera("head_rgbd")
    world_points = xyz.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    checked = 0
    for obj in ground_truth.objects(w):
        if obj.static:
            continue
        mask = (label == labels.index(obj.name)).reshape(-1)
        assert mask.sum() > 500, f"{obj.name} should be in view"
        local = (world_points[mask] - obj.pose[:3, 3]) @ obj.pose[:3, :3]
        d = np.abs(_signed_distance(obj.kind, obj.size, local))
        assert d.max() < 0.002, f"{obj.name}: {d.max() * 1e3:.2f} mm off its surface"
        checked += 1
    assert checked == len(w.info.objects)


def test_depth_noise_follows_the_structured_light_model():
    rng = np.random.default_rng(0)
    for z in (0.8, 1.5, 2.5):
        depth = np.full((200, 200), z, np.float32)
        noisy = noise.structured_light(depth, rng, 580.0)
        assert noisy.shape == depth.shape and np.all(noisy > 0)  # a flat wall has no edges
        step = z**2 / (580.0 * noise.BASELINE * noise.SUBPIXEL)  # quantisation step
        expected = math.sqrt(noise.sigma(z) ** 2 + step**2 / 12)
        assert noisy.std() == pytest.approx(expected, rel=0.25)
        assert abs(noisy.mean() - z) < 3 * expected / 200 + step
    edge = np.full((100, 100), 1.0, np.float32)
    edge[:, 50:] = 2.0
    noisy = noise.structured_light(edge, rng, 580.0)
    assert (noisy[:, 48:52] == 0).mean() > 0.3 and (noisy[:, :45] == 0).mean() == 0


def _drive(world: World, seconds: float) -> np.ndarray:
    speeds = []
    for _ in range(int(seconds / world.timestep)):
        world.step()
        _, _, _, vx, vy, w = world.base_pose()
        speeds.append((math.hypot(vx, vy), abs(w)))
    return np.array(speeds)


@pytest.mark.parametrize(
    ("goal", "path"),
    [((1.0, -0.6, 1.2), None), ((-0.5, 0.8, -2.5), np.array([[0.4, 0.0, 0.0], [0.4, 0.8, 1.5]]))],
    ids=["straight", "path"],
)
def test_base_goal_is_reached_within_2cm_and_2deg_without_exceeding_limits(goal, path):
    w = World("booth", ARMAR6)
    w.set_base_goal(*goal, path=path, goal_id="g1")
    speeds = _drive(w, 15.0)
    x, y, yaw, *_ = w.base_pose()
    assert math.hypot(x - goal[0], y - goal[1]) < 0.02
    assert abs(wrap(yaw - goal[2])) < math.radians(2)
    assert w.base.status == "reached" and w.base.goal_id == "g1"
    assert speeds[:, 0].max() <= ARMAR6.vel_lin * 1.01
    assert speeds[:, 1].max() <= ARMAR6.vel_rot * 1.01
    assert speeds[:, 0].max() > 0.9 * ARMAR6.vel_lin  # and it did use its speed


def test_base_velocity_command_times_out():
    w = World("booth", ARMAR6)
    w.set_base_velocity(0.3, 0.0, 0.0, timeout=0.5)
    _drive(w, 2.0)
    x, *_ = w.base_pose()
    assert 0.1 < x < 0.3  # moved for about half a second, then stopped
    assert w.base_pose()[3] == pytest.approx(0.0, abs=1e-3)


def _rot(axis: str, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return {
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
    }[axis]


def armar6_camera_pose(x, y, yaw, torso, neck_yaw, neck_pitch) -> np.ndarray:
    """T_world_camera by the published ARMAR-6 kinematics (SPEC §2): torso frame 0.83 m + lift
    above the platform, neck yaw then pitch 0.37 m above it, camera 0.1 m up and ahead."""
    R = _rot("z", yaw) @ _rot("z", neck_yaw) @ _rot("y", neck_pitch)
    neck = np.array([x, y, 0.83 + torso + 0.37])
    T = np.eye(4)
    T[:3, 3] = neck + R @ np.array([0.1, 0.0, 0.1])
    # optical frame: z along the head's +x (forward), x along its -y (right), y down
    T[:3, :3] = R @ np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    return T


def test_head_commands_move_the_camera_as_the_kinematics_say():
    w = World("tabletop_clutter", ARMAR6)
    target = {"torso_lift": 0.3, "neck_yaw": 0.4, "neck_pitch": -0.25}
    assert w.command_joints(list(target), "position", np.array(list(target.values()))) == []
    w.step(4000)
    names, q, _ = w.joint_state()
    np.testing.assert_allclose(q, [target[n] for n in names], atol=2e-3)
    x, y, yaw, *_ = w.base_pose()
    expected = armar6_camera_pose(x, y, yaw, *(q[names.index(n)] for n in target))
    T = w.T_world_camera("head_rgbd")
    np.testing.assert_allclose(T[:3, 3], expected[:3, 3], atol=1e-3)
    np.testing.assert_allclose(T[:3, :3], expected[:3, :3], atol=1e-3)


def test_joint_limits_clamp_commands():
    w = World("tabletop_clutter", ARMAR6)
    w.command_joints(["neck_yaw"], "velocity", np.array([3.0]))
    for _ in range(20):  # keep the velocity command alive for 2 s
        w.command_joints(["neck_yaw"], "velocity", np.array([3.0]))
        w.step(100)
    names, q, _ = w.joint_state()
    assert q[names.index("neck_yaw")] == pytest.approx(math.radians(45), abs=5e-3)
    assert w.command_joints(["elbow"], "position", np.array([1.0])) == ["elbow"]


def _log_so3(R: np.ndarray) -> np.ndarray:
    angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    if angle < 1e-12:
        return np.zeros(3)
    return (
        angle
        / (2 * math.sin(angle))
        * np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    )


def test_imu_gyro_measures_the_head_and_reads_gravity_at_rest():
    w = World("localization", ARMAR3)
    _, acc, _ = w.imu()
    assert np.linalg.norm(acc) == pytest.approx(9.81, abs=0.02)
    w.set_disturbance("hip_yaw", math.radians(20), 0.25)
    w.command_joints(["neck_yaw", "neck_roll"], "velocity", np.array([0.5, -0.3]))
    w.step(500)
    site = w._imu_site
    errors = []
    for _ in range(50):
        R0 = w.data.site_xmat[site].reshape(3, 3).copy()
        gyro_before = w.imu()[0]
        w.step()
        R1 = w.data.site_xmat[site].reshape(3, 3)
        omega = _log_so3(R0.T @ R1) / w.timestep  # body-frame rate over the step
        errors.append(np.linalg.norm(omega - (gyro_before + w.imu()[0]) / 2))
        assert np.linalg.norm(w.imu()[0]) > 0.1  # the head really turns
    assert max(errors) < 1e-3
    np.testing.assert_allclose(w.imu()[0], w.head_angular_velocity(), atol=1e-9)


def test_objects_at_rest_sleep_where_they_would_stand_and_the_robot_stays_awake():
    """MuJoCo's sleep skips the resting objects' dynamics and contacts; it must not move them,
    nor stop the robot (actuated) from following its commands."""
    asleep, awake = World("kitchen", ARMAR6), World("kitchen", ARMAR6, sleep=False)
    # the settle is the same (awake): an object slowing on its way down does not sleep short
    np.testing.assert_array_equal(asleep.data.qpos, awake.data.qpos)
    for w in (asleep, awake):
        w.step(20)  # at rest, asleep after mjMINAWAKE (10) steps
    m = asleep.model
    robot = m.body_treeid[m.site_bodyid[asleep._imu_site]]
    objects = [t for t in range(m.ntree) if t != robot]
    assert objects and not asleep.data.tree_awake[objects].any()
    assert asleep.data.tree_awake[robot] and awake.data.tree_awake[objects].all()
    assert asleep.data.ncon == 0 < awake.data.ncon  # their contacts are not even detected
    for w in (asleep, awake):
        w.command_joints(["neck_yaw", "neck_pitch"], "velocity", np.array([0.5, -0.3]))
        w.set_base_velocity(0.1, 0.05, 0.0, 1.0)
        w.step(1000)
    free = [j for j in range(m.njnt) if m.jnt_type[j] == 0]  # the objects' free joints
    adr = np.concatenate([np.arange(m.jnt_qposadr[j], m.jnt_qposadr[j] + 3) for j in free])
    assert len(free) == len(objects)
    np.testing.assert_allclose(asleep.data.qpos[adr], awake.data.qpos[adr], atol=1e-3)
    np.testing.assert_allclose(asleep.data.qpos, awake.data.qpos, atol=1e-3)  # the robot too
    assert abs(asleep.joint_state()[1][0] - awake.joint_state()[1][0]) < 1e-6
