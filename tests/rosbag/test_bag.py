"""Bags in the TUM RGB-D layout, ROS 1 and ROS 2, each depth encoding, read back into the
RgbdFrames they were written from (no Zenoh); and the errors a bad bag or topic gets."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from schemas import RgbdFrame
from services.adapters.rosbag.bag import BagError, BagFrames, BagReplayConfig
from services.adapters.rosbag.convert import fixed_camera_pose
from tests.rosbag.bags import (
    DEPTH,
    EPOCH,
    INFO,
    RGB,
    T_CAMERA_RGB,
    T_RGB_OPTICAL,
    as_stored,
    tabletop_views,
    write_tum_bag,
)


@pytest.fixture(scope="module")
def frames() -> list[RgbdFrame]:
    return tabletop_views(160, 120)[0]


def _bag(tmp_path, frames, ros: int, depth: str = "32FC1", **kw):
    path = tmp_path / ("tum.bag" if ros == 1 else "tum")
    write_tum_bag(path, frames, ros, depth, **kw)
    return path


def _read(path, **kw) -> tuple[list[RgbdFrame], BagFrames]:
    config = BagReplayConfig(**{"rgb": RGB, "depth": DEPTH, "camera_info": INFO, **kw})
    with BagFrames(path, config) as bag:
        return list(bag), bag


@pytest.mark.parametrize(
    ("ros", "depth", "rgb"),
    [(1, "32FC1", "rgb8"), (1, "16UC1", "bgr8"), (2, "32FC1", "bgr8"), (2, "16UC1", "rgb8")],
)
def test_a_bag_gives_back_the_frames_it_was_written_from(tmp_path, frames, ros, depth, rgb):
    path = _bag(tmp_path, frames, ros, depth, rgb_encoding=rgb)
    got, bag = _read(path, tf=True, camera="desk_cam")
    assert len(got) == len(frames) and not bag.skipped  # the decoy colour image pairs nothing
    assert (bag.world_frame, bag.camera_frame) == ("world", "openni_rgb_optical_frame")
    for i, (g, f) in enumerate(zip(got, frames, strict=True)):
        want = as_stored(f, depth)
        assert g.seq == i and g.camera == "desk_cam"
        assert abs(g.stamp - (EPOCH + f.stamp)) < 1e-6
        assert g.intrinsics == f.intrinsics
        np.testing.assert_array_equal(g.rgb, f.rgb)
        np.testing.assert_array_equal(g.depth, want.depth)  # bit for bit: NaN → 0, mm → m
        np.testing.assert_allclose(g.T_world_camera, f.T_world_camera, atol=1e-12)
    if depth == "16UC1":  # whole millimetres, and never more than half of one off
        assert 0 < np.abs(got[0].depth - frames[0].depth).max() <= 0.0005 + 1e-6


@pytest.mark.parametrize(("ros", "depth", "codec"), [(1, "16UC1", "png"), (2, "32FC1", "jpeg")])
def test_a_bag_of_compressed_images_gives_back_its_frames(tmp_path, frames, ros, depth, codec):
    """CompressedImage colour (PNG lossless, JPEG within its artefacts) and compressedDepth
    depth (16UC1 mm lossless; 32FC1 quantised inverse depth, d² / 10100 at worst)."""
    path = _bag(tmp_path, frames, ros, depth, compressed=codec)
    got, bag = _read(path, tf=True)
    assert len(got) == len(frames) and not bag.skipped
    for g, f in zip(got, frames, strict=True):
        want = as_stored(f, depth)
        if codec == "png":
            np.testing.assert_array_equal(g.rgb, f.rgb)
        else:
            assert g.rgb.shape == f.rgb.shape and np.abs(g.rgb.astype(int) - f.rgb).mean() < 4
        valid = want.depth > 0
        np.testing.assert_array_equal(g.depth > 0, valid)
        step = want.depth**2 / 10100 if depth == "32FC1" else np.zeros_like(want.depth)
        assert np.all(np.abs(g.depth - want.depth)[valid] <= (step / 2 + 1e-6)[valid])


def test_a_compressed_format_it_cannot_read_names_the_topic(tmp_path, frames):
    path = _bag(tmp_path, frames, 1, "16UC1", compressed="png")
    with pytest.raises(BagError, match="--depth topic /camera/rgb/image_color: compressed "
                       "depth format 'rgb8; png compressed rgb8': the depth encoding"):  # fmt: skip
        _read(path, rgb=DEPTH, depth=RGB)


def test_pose_without_tf_world_frame_limit_and_start(tmp_path, frames):
    path = _bag(tmp_path, frames, 1)
    T_fixed = fixed_camera_pose(0.5, 0, 1.2, 0, 0.3, 0)
    got, _ = _read(path, T_world_camera=T_fixed)
    assert all(np.array_equal(g.T_world_camera, T_fixed) for g in got)
    got, _ = _read(path, tf=True, world_frame="/openni_camera", limit=2)
    assert len(got) == 2
    np.testing.assert_allclose(got[1].T_world_camera, T_CAMERA_RGB @ T_RGB_OPTICAL, atol=1e-12)
    got, _ = _read(path, start=0.3)  # the bag starts with the decoy 40 ms before frame 0
    assert [round(g.stamp - EPOCH, 3) for g in got] == [0.5]


def test_unpaired_images_are_skipped_and_counted(tmp_path, frames):
    path = _bag(tmp_path, frames, 2, rgb_delay=0.025)
    got, bag = _read(path)
    assert got == [] and bag.skipped == {"unpaired": 3}
    got, bag = _read(path, max_dt=0.03)
    assert len(got) == 3


def test_bad_bags_and_topics_are_named(tmp_path, frames):
    path = _bag(tmp_path, frames, 1, with_tf=False)
    with pytest.raises(BagError, match=r"--depth topic /camera/depth/img is not in the bag "
                       r"\(topics: /camera/depth/image \(sensor_msgs/msg/Image\)"):  # fmt: skip
        _read(path, depth="/camera/depth/img")
    with pytest.raises(BagError, match="--camera-info topic /camera/rgb/image_color carries "
                       "sensor_msgs/msg/Image, not sensor_msgs/msg/CameraInfo"):  # fmt: skip
        _read(path, camera_info=RGB)
    with pytest.raises(BagError, match="--tf: the bag has no /tf or /tf_static topic"):
        _read(path, tf=True)
    with pytest.raises(BagError, match="--depth topic /camera/rgb/image_color: depth image "
                       "encoding 'rgb8' is not supported"):  # fmt: skip
        _read(path, rgb=DEPTH, depth=RGB)
    with pytest.raises(BagError, match="no such file"):
        _read(tmp_path / "missing.bag")
    (tmp_path / "tf").mkdir()
    tf_bag = _bag(tmp_path / "tf", frames, 2)
    with pytest.raises(BagError, match="'map' is not in the bag's tf tree"):
        _read(tf_bag, tf=True, world_frame="map")


def test_a_ros2_bag_without_message_definitions_reads_with_humbles(tmp_path, frames):
    """rosbag2 before Iron stored no message definitions (rosbags then needs a typestore)."""
    path = _bag(tmp_path, frames, 2, "16UC1")
    with sqlite3.connect(next(path.glob("*.db3"))) as db:
        db.execute("DELETE FROM message_definitions")
    got, _ = _read(path, tf=True)
    assert len(got) == 3
    np.testing.assert_array_equal(got[2].depth, as_stored(frames[2], "16UC1").depth)
    np.testing.assert_allclose(got[2].T_world_camera, frames[2].T_world_camera, atol=1e-12)
