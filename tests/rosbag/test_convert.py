"""The pure parts of the bag replay: image buffers, depth units, intrinsics, poses, the tf
tree's interpolation and the pairing of colour and depth by stamp."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.adapters.rosbag.bag import pair_by_stamp
from services.adapters.rosbag.convert import (
    ConversionError,
    depth_from_image,
    depth_to_metres,
    fixed_camera_pose,
    image_array,
    intrinsics_from_camera_info,
    quaternion_matrix,
    rgb_from_image,
)
from services.adapters.rosbag.tf import ExtrapolationError, TfError, TransformTree


def test_padded_big_endian_16uc1_rows_decode_to_millimetres_in_metres():
    values = np.array([[1234, 0], [65535, 7]], ">u2")
    rows = [values[r].tobytes() + b"\xff\xff" for r in range(2)]  # step 6: 2 bytes of padding
    pixels = image_array("16UC1", 2, 2, 6, b"".join(rows), bigendian=True)
    assert pixels.dtype == np.uint16 and pixels.tolist() == [[1234, 0], [65535, 7]]
    metres = depth_from_image(pixels, "16UC1")
    assert metres.dtype == np.float32
    np.testing.assert_allclose(metres, [[1.234, 0.0], [65.535, 0.007]], rtol=1e-6)
    assert metres[0, 1] == 0.0


def test_32fc1_depth_keeps_metres_and_zeroes_what_is_no_return():
    raw = np.array([[2.5, np.nan], [np.inf, -1.0]], "<f4")
    pixels = image_array("32FC1", 2, 2, 8, raw.tobytes())
    assert depth_from_image(pixels, "32FC1").tolist() == [[2.5, 0.0], [0.0, 0.0]]


def test_integer_depth_with_a_sensor_scale_as_a_realsense_gives_it():
    z16 = np.array([[4000, 1]], np.uint16)
    np.testing.assert_allclose(depth_to_metres(z16, 0.00025), [[1.0, 0.00025]], rtol=1e-6)
    assert depth_to_metres(np.array([[1.5]], np.float64)).dtype == np.float32


@pytest.mark.parametrize(
    ("encoding", "raw", "rgb"),
    [
        ("rgb8", [10, 20, 30], [10, 20, 30]),
        ("bgr8", [10, 20, 30], [30, 20, 10]),
        ("rgba8", [10, 20, 30, 255], [10, 20, 30]),
        ("bgra8", [10, 20, 30, 255], [30, 20, 10]),
        ("mono8", [77], [77, 77, 77]),
    ],
)
def test_colour_encodings_become_rgb(encoding, raw, rgb):
    pixels = image_array(encoding, 1, 1, len(raw), bytes(raw))
    out = rgb_from_image(pixels, encoding)
    assert out.shape == (1, 1, 3) and out.dtype == np.uint8 and out[0, 0].tolist() == rgb


def test_bad_images_are_refused_with_what_is_wrong():
    with pytest.raises(ConversionError, match="'yuv422' is not supported"):
        image_array("yuv422", 1, 1, 2, b"\0\0")
    with pytest.raises(ConversionError, match="step 2 and 2 bytes"):
        image_array("rgb8", 1, 1, 2, b"\0\0")
    with pytest.raises(ConversionError, match="depth image encoding 'rgb8'"):
        depth_from_image(np.zeros((1, 1, 3), np.uint8), "rgb8")
    with pytest.raises(ConversionError, match="colour image encoding '32FC1'"):
        rgb_from_image(np.zeros((1, 1), np.float32), "32FC1")


def test_camera_info_k_gives_pinhole_intrinsics():
    K = intrinsics_from_camera_info([525.0, 0, 319.5, 0, 526.0, 239.5, 0, 0, 1], 640, 480)
    assert (K.fx, K.fy, K.cx, K.cy, K.width, K.height) == (525.0, 526.0, 319.5, 239.5, 640, 480)
    with pytest.raises(ConversionError, match="not calibrated"):
        intrinsics_from_camera_info([0.0] * 9, 640, 480)


def test_quaternions_are_x_y_z_w_as_in_ros():
    s = math.sqrt(0.5)
    np.testing.assert_allclose(quaternion_matrix(0, 0, s, s), [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
                               atol=1e-12)  # fmt: skip


def test_a_fixed_pose_of_the_body_frame_gives_an_optical_frame():
    T = fixed_camera_pose(1.0, 2.0, 1.2, 0.0, math.radians(30), math.radians(90))
    # body x (forward) points along world +y, 30° down: the optical z axis
    np.testing.assert_allclose(T[:3, 2], [0, math.cos(math.radians(30)), -0.5], atol=1e-12)
    np.testing.assert_allclose(T[:3, 0], [1, 0, 0], atol=1e-12)  # right of +y is +x
    assert T[:3, 1][2] < 0 and np.allclose(T[:3, 3], [1, 2, 1.2])  # image down: world down


def _tree() -> TransformTree:
    tree = TransformTree(tolerance=0.05)
    s = math.sqrt(0.5)
    tree.add("/world", "/base", 10.0, (0, 0, 0), (0, 0, 0, 1))
    tree.add("/world", "/base", 11.0, (1, 0, 0), (0, 0, s, s))  # 90° about z, 1 m along x
    tree.add("base", "camera", 0.0, (0, 0, 1), (0, 0, 0, 1), static=True)
    return tree


def test_tf_interpolates_each_edge_and_composes_the_chain():
    tree = _tree()
    assert tree.chain("camera") == ["camera", "base", "world"] and tree.root("camera") == "world"
    assert tree.roots == {"world"}
    T = tree.lookup("/camera", 10.5)
    c, s = math.cos(math.pi / 4), math.sin(math.pi / 4)
    np.testing.assert_allclose(T[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [0.5, 0, 1], atol=1e-12)
    np.testing.assert_allclose(tree.lookup("camera", 10.5, target="base")[:3, 3], [0, 0, 1])
    np.testing.assert_allclose(tree.lookup("camera", 11.04)[:3, 3], [1, 0, 1])  # tolerance


def test_tf_names_frames_it_lacks_and_times_it_never_saw():
    tree = _tree()
    with pytest.raises(ExtrapolationError, match=r"world → base: 11\.200 s is outside"):
        tree.lookup("camera", 11.2)
    with pytest.raises(TfError, match=r"'lens' is not in the bag's tf tree .*camera"):
        tree.lookup("lens", 10.0)
    tree.add("world", "other", 0.0, (0, 0, 0), (0, 0, 0, 1), static=True)
    with pytest.raises(TfError, match="'other' is not above 'camera'"):
        tree.lookup("camera", 10.0, target="other")
    with pytest.raises(TfError, match="two parents"):
        tree.add("other", "base", 10.0, (0, 0, 0), (0, 0, 0, 1))


def test_depth_pairs_with_the_nearest_colour_within_the_window():
    depth = {"d0": 0.000, "d1": 0.033, "d2": 0.100, "d3": 0.200}
    rgb = {"r0": 0.012, "r1": 0.030, "r2": 0.125, "r3": 0.190}
    stream = sorted([("depth", t, n) for n, t in depth.items()]
                    + [("rgb", t, n) for n, t in rgb.items()], key=lambda x: x[1])  # fmt: skip
    pairs = list(pair_by_stamp(stream, 0.02))
    assert [(d, r) for _t, d, r in pairs] == [("d0", "r0"), ("d1", "r1"), ("d2", None),
                                              ("d3", "r3")]  # fmt: skip
    assert [t for t, _d, _r in pairs] == list(depth.values())
    # colour logged before an earlier depth image (stamps out of log order) still pairs
    late = [("rgb", 0.012, "r0"), ("rgb", 0.045, "r1"), ("depth", 0.0, "d0"), ("depth", 0.04, "d1")]
    assert [(d, r) for _t, d, r in pair_by_stamp(late, 0.02)] == [("d0", "r0"), ("d1", "r1")]


def test_compressed_depth_decodes_as_compressed_depth_image_transport_encodes():
    """16UC1: millimetres, lossless; 32FC1: inverse depth quantised (A = 10100, B = −1009 for
    10 m and 100 levels), within the quantisation step (d² / A: 0.4 mm at 2 m); 0 is none."""
    from services.adapters.rosbag.convert import depth_from_compressed
    from tests.rosbag.bags import compressed_depth

    depth = np.array([[0.0, 0.5, 1.0], [2.0, 3.25, 7.5]], np.float32)
    fmt, data = compressed_depth(np.round(depth * 1000), "16UC1")
    assert fmt == "16UC1; compressedDepth png"
    np.testing.assert_allclose(depth_from_compressed(fmt, data), depth, atol=1e-6)
    fmt, data = compressed_depth(depth, "32FC1")
    got = depth_from_compressed(fmt, data)
    assert got[0, 0] == 0.0
    step = depth**2 / 10100
    assert np.all(np.abs(got - depth) <= step / 2 + 1e-6), got - depth


def test_compressed_colour_decodes_jpeg_and_png():
    from services.adapters.rosbag.convert import rgb_from_compressed
    from tests.rosbag.bags import encoded

    rgb = np.zeros((16, 24, 3), np.uint8)
    rgb[:, :12] = (200, 40, 10)
    np.testing.assert_array_equal(rgb_from_compressed("png", encoded(rgb, "png")), rgb)
    jpeg = rgb_from_compressed("rgb8; jpeg compressed bgr8", encoded(rgb, "jpeg"))
    assert jpeg.shape == rgb.shape and np.abs(jpeg.astype(int) - rgb).mean() < 3


@pytest.mark.parametrize(
    ("which", "fmt", "data", "message"),
    [
        ("depth", "16UC1; compressedDepth jpeg", b"\x00" * 20, "png only"),
        ("depth", "8UC1; compressedDepth png", b"", "must be 16UC1 or 32FC1"),
        ("depth", "16UC1; compressedDepth png", b"\x00" * 12 + b"nonsense", "no image PIL"),
        ("colour", "16UC1; compressedDepth png", b"", "is a compressedDepth depth image"),
        ("colour", "theora", b"", r"not supported \(jpeg, png\)"),
    ],
)
def test_bad_compressed_images_say_what_is_wrong(which, fmt, data, message):
    from services.adapters.rosbag.convert import depth_from_compressed, rgb_from_compressed

    decode = depth_from_compressed if which == "depth" else rgb_from_compressed
    with pytest.raises(ConversionError, match=message):
        decode(fmt, data)
