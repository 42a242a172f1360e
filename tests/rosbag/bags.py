"""Bags in the TUM RGB-D layout written with rosbags from AVS frames, for the replay tests.

Topics as in TUM's bags: ``/camera/rgb/image_color``, ``/camera/depth/image``,
``/camera/rgb/camera_info`` and ``/tf`` (ROS 1: ``tf/tfMessage`` with the camera's mounting
transforms repeated on ``/tf``, as TUM's are; ROS 2: ``tf2_msgs/TFMessage``, the mounting
transforms once on ``/tf_static``). The tree is ``world → openni_camera`` (the moving body
frame: x forward, y left, z up) ``→ openni_rgb_frame → openni_rgb_optical_frame`` (x right,
y down, z forward), so the pose of the frames' optical frame is rebuilt only by composing it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from schemas import RgbdFrame

RGB, DEPTH, INFO = "/camera/rgb/image_color", "/camera/depth/image", "/camera/rgb/camera_info"
EPOCH = 1_305_031_102.0  # stamps like TUM's (2011)
#: the optical frame in the camera body frame: x_opt = -y_body, y_opt = -z_body, z_opt = x_body
R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
#: openni_camera → openni_rgb_frame: the colour camera 2.5 cm to the right of the body origin
T_CAMERA_RGB = np.eye(4)
T_CAMERA_RGB[:3, 3] = (0.0, -0.025, 0.0)
T_RGB_OPTICAL = np.eye(4)
T_RGB_OPTICAL[:3, :3] = R_BODY_OPTICAL


def _ns(t: float) -> int:
    return round(t * 1e9)


def write_tum_bag(
    path: Path,
    frames: list[RgbdFrame],
    ros: int,
    depth_encoding: str,
    rgb_encoding: str = "rgb8",
    rgb_delay: float = 0.007,
    decoy_rgb: bool = True,
    with_tf: bool = True,
    compressed: str | None = None,
) -> list[float]:
    """Write ``frames`` as a bag at ``path`` (ROS 1: a ``.bag`` file; ROS 2: a directory);
    depth in ``depth_encoding`` (16UC1: millimetres; 32FC1: metres). Each colour image is
    stamped ``rgb_delay`` after its depth image; with ``decoy_rgb`` a colour image 40 ms
    before the first depth image has no depth partner; ``with_tf=False`` leaves out /tf and
    /tf_static. ``compressed`` ("png", "jpeg"): colour as ``sensor_msgs/CompressedImage`` in
    that codec and depth as ``compressedDepth`` (a 12-byte header, then a 16-bit PNG: mm for
    16UC1, quantised inverse depth for 32FC1, as compressed_depth_image_transport writes
    them). Returns the depth images' stamps."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    if ros == 1:
        from rosbags.rosbag1 import Writer

        store = get_typestore(Stores.ROS1_NOETIC)
        store.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms",
                                          "tf/msg/tfMessage"))  # fmt: skip
        tf_type, slash, writer = "tf/msg/tfMessage", "/", Writer(path)
        serialize = store.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer

        store = get_typestore(Stores.ROS2_HUMBLE)
        tf_type, slash, writer = "tf2_msgs/msg/TFMessage", "", Writer(path, version=9)
        serialize = store.serialize_cdr
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Image, Info = T["sensor_msgs/msg/Image"], T["sensor_msgs/msg/CameraInfo"]
    Compressed = T["sensor_msgs/msg/CompressedImage"]
    Roi = T["sensor_msgs/msg/RegionOfInterest"]
    Tf, Transform = T["geometry_msgs/msg/TransformStamped"], T["geometry_msgs/msg/Transform"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    optical = f"{slash}openni_rgb_optical_frame"

    def header(t: float, frame_id: str, seq: int = 0):
        stamp = Time(sec=_ns(t) // 10**9, nanosec=_ns(t) % 10**9)
        if ros == 1:
            return Header(seq=seq, stamp=stamp, frame_id=frame_id)
        return Header(stamp=stamp, frame_id=frame_id)

    def image(t: float, pixels: np.ndarray, encoding: str, seq: int):
        h, w = pixels.shape[:2]
        data = np.ascontiguousarray(pixels).view(np.uint8).reshape(-1)
        return Image(header=header(t, optical, seq), height=h, width=w, encoding=encoding,
                     is_bigendian=0, step=data.size // h, data=data)  # fmt: skip

    def packed(t: float, pixels: np.ndarray, encoding: str, seq: int):
        if encoding in ("16UC1", "32FC1"):
            fmt, data = compressed_depth(pixels, encoding)
        else:
            fmt, data = (
                f"{encoding}; {compressed} compressed {encoding}",
                encoded(pixels if encoding == "rgb8" else pixels[:, :, ::-1], compressed),
            )
        return Compressed(header=header(t, optical, seq), format=fmt,
                          data=np.frombuffer(data, np.uint8))  # fmt: skip

    if compressed:
        image = packed  # the compressed form of the same images

    def transform(t: float, parent: str, child: str, M: np.ndarray):
        x, y, z, w = Rotation.from_matrix(M[:3, :3]).as_quat()
        tr = Transform(translation=Vector3(x=M[0, 3], y=M[1, 3], z=M[2, 3]),
                       rotation=Quaternion(x=x, y=y, z=z, w=w))  # fmt: skip
        return Tf(header=header(t, slash + parent), child_frame_id=slash + child, transform=tr)

    def mounting(t: float) -> list:
        return [
            transform(t, "openni_camera", "openni_rgb_frame", T_CAMERA_RGB),
            transform(t, "openni_rgb_frame", "openni_rgb_optical_frame", T_RGB_OPTICAL),
        ]

    stamps = []
    with writer:

        def add(topic: str, msgtype: str):
            return writer.add_connection(topic, msgtype, typestore=store)

        kind = (Compressed if compressed else Image).__msgtype__
        c_rgb, c_depth = add(RGB, kind), add(DEPTH, kind)
        c_info = add(INFO, Info.__msgtype__)
        c_tf = add("/tf", tf_type) if with_tf else None
        put = lambda c, t, msg: writer.write(c, _ns(t), serialize(msg, c.msgtype))  # noqa: E731
        t0 = EPOCH + frames[0].stamp
        if ros == 2 and with_tf:
            c_static = add("/tf_static", tf_type)
            put(c_static, t0 - 0.1, T[tf_type](transforms=mounting(t0 - 0.1)))
        if decoy_rgb:
            put(c_rgb, t0 - 0.04, image(t0 - 0.04, frames[0].rgb, "rgb8", 0))
        for i, f in enumerate(frames):
            t = EPOCH + f.stamp
            stamps.append(t)
            T_body = f.T_world_camera @ np.linalg.inv(T_CAMERA_RGB @ T_RGB_OPTICAL)
            moving = [transform(t, "world", "openni_camera", T_body)]
            if with_tf:
                put(c_tf, t, T[tf_type](transforms=moving + (mounting(t) if ros == 1 else [])))
            K = f.intrinsics.K()
            matrices = {"d": np.zeros(5), "k": K.reshape(-1), "r": np.eye(3).reshape(-1),
                        "p": np.c_[K, np.zeros(3)].reshape(-1)}  # fmt: skip
            if ros == 1:  # ROS 1 spells them in capitals
                matrices = {name.upper(): value for name, value in matrices.items()}
            roi = Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
            info = Info(header=header(t, optical, i), height=f.intrinsics.height,
                        width=f.intrinsics.width, distortion_model="plumb_bob", binning_x=0,
                        binning_y=0, roi=roi, **matrices)  # fmt: skip
            put(c_info, t, info)
            if depth_encoding == "16UC1":
                depth = np.round(f.depth * 1000).astype(np.uint16)
            else:
                depth = np.where(f.depth > 0, f.depth, np.nan).astype(np.float32)  # TUM: NaN
            put(c_depth, t, image(t, depth, depth_encoding, i))
            rgb = f.rgb if rgb_encoding == "rgb8" else np.ascontiguousarray(f.rgb[:, :, ::-1])
            put(c_rgb, t + rgb_delay, image(t + rgb_delay, rgb, rgb_encoding, i))
    return stamps


def encoded(pixels: np.ndarray, codec: str) -> bytes:
    """An image's bytes in ``codec`` (png, jpeg)."""
    import io

    from PIL import Image as PilImage

    out = io.BytesIO()
    PilImage.fromarray(pixels).save(out, format="PNG" if codec == "png" else "JPEG", quality=95)
    return out.getvalue()


#: compressed_depth_image_transport's defaults for 32FC1: depth_max 10 m, quantisation 100
DEPTH_QUANT_A = 100 * 101.0
DEPTH_QUANT_B = 1.0 - DEPTH_QUANT_A / 10.0


def compressed_depth(depth: np.ndarray, encoding: str) -> tuple[str, bytes]:
    """(format, data) of a compressedDepth message: ConfigHeader (int32 format 1 = PNG, two
    float32 quantisation parameters) + a 16-bit PNG. 16UC1: the millimetres as they are;
    32FC1: inverse depth A / d + B (0: no depth)."""
    if encoding == "16UC1":
        values, a, b = depth.astype(np.uint16), 0.0, 0.0
    else:
        d = np.nan_to_num(depth.astype(np.float64), nan=0.0)
        values = np.zeros(d.shape, np.uint16)
        ok = d > 0
        values[ok] = np.round(DEPTH_QUANT_A / d[ok] + DEPTH_QUANT_B).astype(np.uint16)
        a, b = DEPTH_QUANT_A, DEPTH_QUANT_B
    header = np.array([1], "<i4").tobytes() + np.array([a, b], "<f4").tobytes()
    return f"{encoding}; compressedDepth png", header + encoded(values, "png")


def as_stored(frame: RgbdFrame, depth_encoding: str) -> RgbdFrame:
    """The frame as a bag in ``depth_encoding`` carries it: depth in whole millimetres for
    16UC1 (converted back to float32 metres as the replay does)."""
    if depth_encoding != "16UC1":
        return frame
    mm = np.round(frame.depth * 1000).astype(np.uint16)
    return frame.model_copy(update={"depth": mm.astype(np.float32) * np.float32(0.001)})


def tabletop_views(
    width: int = 320, height: int = 240, yaws: tuple[float, ...] = (-0.2, 0.0, 0.2)
) -> tuple[list[RgbdFrame], dict[str, np.ndarray]]:
    """Frames of tabletop_clutter from the robot's start, the neck turned to each of ``yaws``
    (rad) 0.25 s apart, without the robot's joints (a bag has none); and the true centre of
    each object, with the table top's height as ``table_top``."""
    from services.sim import capture, ground_truth
    from services.sim.render import CameraRenderer
    from services.sim.robots import ARMAR6
    from services.sim.world import World

    world = World("tabletop_clutter", ARMAR6)
    renderer = CameraRenderer(world.model, width, height)
    frames = []
    for i, yaw in enumerate(yaws):
        world.place(neck_yaw=yaw)
        T, _ = capture.snapshot(world, renderer, "head_rgbd")
        f = capture.frame(world, renderer, "head_rgbd", T, 0.25 * i, i, None)
        frames.append(f.model_copy(update={"joint_names": [], "joint_positions": None,
                                           "depth_min": 0.0, "depth_max": 0.0}))  # fmt: skip
    truth = {o.name: o.pose[:3, 3].copy() for o in ground_truth.objects(world)}
    table = next(o for o in ground_truth.objects(world) if o.name == "table")
    truth["table_top"] = np.array([*table.pose[:2, 3], table.pose[2, 3] + table.size[2] / 2])
    renderer.close()
    return frames, truth
