"""The RealSense adapter's pure parts, with plain arrays: depth units → metres, colour formats,
the fixed camera pose, extrinsics, gravity tilt, IMU pairing, the latest-only slot, and that
nothing of it needs pyrealsense2."""

from __future__ import annotations

import subprocess
import sys
import threading
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from services.adapters.realsense import core
from services.adapters.realsense.config import RealsenseSettings
from services.adapters.realsense.node import LatestSlot
from tests.conftest import ROOT


def test_depth_units_become_metres_with_out_of_range_as_no_return() -> None:
    z16 = np.array([[0, 1000, 2999], [3001, 65535, 299]], np.uint16)
    d = core.depth_metres(z16, 0.001, depth_min=0.3, depth_max=3.0)
    assert d.dtype == np.float32
    np.testing.assert_allclose(d, [[0, 1.0, 2.999], [0, 0, 0]], atol=1e-6)
    d = core.depth_metres(z16, 1e-4)  # a D405's scale; no range cut
    np.testing.assert_allclose(d, [[0, 0.1, 0.2999], [0.3001, 6.5535, 0.0299]], atol=1e-6)
    d[0, 1] = 7.0
    assert z16[0, 1] == 1000  # a copy, never a view of the frame's memory
    with pytest.raises(ValueError, match="uint16"):
        core.depth_metres(z16.astype(np.int32), 0.001)


@pytest.mark.parametrize("fmt", ["rgb8", "bgr8", "rgba8", "bgra8", "format.bgr8"])
def test_colour_formats_become_rgb(fmt: str) -> None:
    rgb = np.random.default_rng(1).integers(0, 256, (4, 5, 3), dtype=np.uint8)
    name = fmt.rsplit(".", 1)[-1]
    image = rgb[..., ::-1] if name.startswith("bgr") else rgb
    if name.endswith("a8"):
        image = np.concatenate([image, np.full((4, 5, 1), 255, np.uint8)], axis=2)
    out = core.to_rgb(np.ascontiguousarray(image), fmt)
    np.testing.assert_array_equal(out, rgb)
    assert out.flags.c_contiguous and not np.shares_memory(out, image)


def test_unknown_colour_format_is_refused() -> None:
    with pytest.raises(ValueError, match="yuyv"):
        core.to_rgb(np.zeros((2, 2, 2), np.uint8), "yuyv")


def test_fixed_pose_looks_where_it_says() -> None:
    T = core.T_world_camera(1.0, 2.0, 1.2, yaw_deg=0, pitch_deg=0)
    R = T[:3, :3]
    np.testing.assert_allclose(R[:, 2], [1, 0, 0], atol=1e-12)  # optical axis along +x
    np.testing.assert_allclose(R[:, 0], [0, -1, 0], atol=1e-12)  # image x to the right
    np.testing.assert_allclose(R[:, 1], [0, 0, -1], atol=1e-12)  # image y down
    np.testing.assert_allclose(T[:3, 3], [1, 2, 1.2])

    T = core.T_world_camera(0, 0, 1.5, yaw_deg=90, pitch_deg=30, roll_deg=10)
    R = T[:3, :3]
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    np.testing.assert_allclose(R[:, 2], [0, c, -s], atol=1e-12)  # along +y, 30° down
    # a point 2 m down the optical axis lies 2·sin 30° = 1 m below the camera
    p = T @ np.array([0, 0, 2.0, 1])
    np.testing.assert_allclose(p[:3], [0, 2 * c, 0.5], atol=1e-12)
    # roll turns the image about the axis: image x is no longer level
    assert R[2, 0] == pytest.approx(-np.sin(np.radians(10)) * c, abs=1e-12)


@pytest.mark.parametrize(("pitch", "roll"), [(0, 0), (30, 0), (-20, 5), (60, -15), (85, 30)])
def test_gravity_tilt_inverts_the_pose(pitch: float, roll: float) -> None:
    R = core.T_world_camera(0, 0, 1, yaw_deg=37, pitch_deg=pitch, roll_deg=roll)[:3, :3]
    resting = R.T @ np.array([0, 0, core.GRAVITY])  # specific force at rest, camera axes
    assert core.gravity_tilt(resting) == pytest.approx((pitch, roll), abs=1e-9)


def test_extrinsics_are_column_major() -> None:
    R = Rotation.from_euler("xyz", [3, -7, 11], degrees=True).as_matrix()
    t = [0.015, -0.001, 0.002]
    T = core.extrinsics_matrix(R.T.ravel().tolist(), t)  # librealsense's column-major storage
    np.testing.assert_allclose(T[:3, :3], R)
    np.testing.assert_allclose(T @ [1, 0, 0, 1], [*(R[:, 0] + t), 1])


def test_quaternion_is_w_first() -> None:
    np.testing.assert_allclose(core.quaternion(np.eye(3)), [1, 0, 0, 0])
    Rz = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    h = np.sqrt(0.5)
    np.testing.assert_allclose(core.quaternion(Rz), [h, 0, 0, h], atol=1e-12)
    R = Rotation.from_euler("x", 270, degrees=True).as_matrix()
    assert core.quaternion(R)[0] >= 0


def test_intrinsics_from_a_stream_profile() -> None:
    intr = SimpleNamespace(
        width=640, height=480, fx=615.2, fy=615.9, ppx=322.1, ppy=241.3, coeffs=[0.0] * 5
    )
    K = core.camera_intrinsics(intr)
    assert (K.width, K.height, K.fx, K.fy, K.cx, K.cy) == (640, 480, 615.2, 615.9, 322.1, 241.3)
    assert not core.distorted(intr)
    intr.coeffs = [0.1, -0.05, 0, 0, 0]
    assert core.distorted(intr)


def test_imu_pairing_copies_the_newest_accel() -> None:
    pairing = core.ImuPairing()
    assert pairing.gyro(0.0, (1, 2, 3)) is None  # no accel yet
    pairing.accel((0, -9.8, 0))
    pairing.accel((0.1, -9.7, 0.2))
    s = pairing.gyro(0.005, (0.01, 0.02, 0.03))
    assert s is not None and s.stamp == 0.005
    np.testing.assert_array_equal(s.angular_velocity, [0.01, 0.02, 0.03])
    np.testing.assert_array_equal(s.linear_acceleration, [0.1, -9.7, 0.2])
    assert s.angular_velocity.dtype == s.linear_acceleration.dtype == np.float64


def test_latest_slot_keeps_the_newest() -> None:
    slot: LatestSlot[int] = LatestSlot()
    assert slot.take(0.01) is None
    assert slot.put(1) is False
    assert slot.put(2) is True  # 1 was never taken: dropped
    assert slot.take(0.01) == 2
    assert slot.take(0.01) is None
    threading.Timer(0.05, slot.put, args=(3,)).start()
    assert slot.take(2.0) == 3  # a waiting take wakes on put


def test_settings_from_env_and_flags() -> None:
    s = RealsenseSettings.from_args(
        ["--pitch", "25", "--z", "0.9", "--camera", "desk"],
        env={"AVS_REALSENSE_DEPTH_MAX": "2.5", "AVS_ROBOT": "armar3"},
    )
    assert (s.pitch, s.z, s.camera, s.depth_max, s.robot) == (25, 0.9, "desk", 2.5, "armar3")
    assert (s.width, s.height, s.fps, s.imu) == (640, 480, 30, True)
    with pytest.raises(SystemExit):
        RealsenseSettings.from_args(["--depth-min", "3", "--depth-max", "2"], env={})
    with pytest.raises(SystemExit):
        RealsenseSettings.from_args(["--camera", "a/b"], env={})


def test_pyrealsense2_is_optional() -> None:
    """The adapter's modules import without pyrealsense2; running it says how to install it."""
    code = (
        "import sys; sys.modules['pyrealsense2'] = None\n"  # as if not installed
        "import services.adapters.realsense.node, services.adapters.realsense.core\n"
        "from services.adapters.realsense.__main__ import main\n"
        "sys.exit(main(['--no-multicast', '--mode', 'peer']))\n"
    )
    p = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert p.returncode == 2, p.stderr
    assert "pip install 'avs[realsense]'" in p.stderr
