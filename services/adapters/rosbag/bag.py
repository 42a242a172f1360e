"""RGB-D frames out of a ROS 1 or ROS 2 bag (rosbags: no ROS install): colour and depth
images paired by the nearest header stamp, intrinsics from CameraInfo, and the camera pose
from the bag's tf tree or a fixed pose. No Zenoh here: ``BagFrames`` yields RgbdFrames.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from schemas import CameraIntrinsics, RgbdFrame
from services.adapters.rosbag.convert import (
    ConversionError,
    depth_from_compressed,
    depth_from_image,
    fixed_camera_pose,
    has_distortion,
    image_array,
    intrinsics_from_camera_info,
    rgb_from_compressed,
    rgb_from_image,
)
from services.adapters.rosbag.tf import ExtrapolationError, TfError, TransformTree, frame_name

log = logging.getLogger("avs.adapters.rosbag")

IMAGE_TYPE = "sensor_msgs/msg/Image"
COMPRESSED_TYPE = "sensor_msgs/msg/CompressedImage"
INFO_TYPE = "sensor_msgs/msg/CameraInfo"
TF_TOPICS = ("/tf", "/tf_static")

A = TypeVar("A")
B = TypeVar("B")


class BagError(ValueError):
    """A bag that cannot be replayed as asked: a missing topic, a wrong message type or
    encoding, no calibration, no tf. The message names the problem."""


@dataclass
class BagReplayConfig:
    """What to read from a bag and how to turn it into RgbdFrames."""

    rgb: str
    depth: str
    camera_info: str
    camera: str = "head_rgbd"
    #: take the pose from the bag's tf tree (else ``T_world_camera``)
    tf: bool = False
    #: the tf frame that is the world (None: the root of the camera frame's tree)
    world_frame: str | None = None
    #: the fixed optical-frame pose without tf (default: the camera body frame is the world)
    T_world_camera: np.ndarray = field(default_factory=lambda: fixed_camera_pose(0, 0, 0, 0, 0, 0))
    #: colour and depth whose stamps differ by more are not paired (s)
    max_dt: float = 0.02
    #: metres per unit of integer depth (16UC1); None: millimetres
    depth_scale: float | None = None
    #: what the frames say about the sensor's valid range (0: unknown)
    depth_min: float = 0.0
    depth_max: float = 0.0
    #: skip this many seconds of the bag's start
    start: float = 0.0
    #: stop after this many frames (0: all)
    limit: int = 0
    #: how far beyond the recorded tf a pose may be taken (s)
    tf_tolerance: float = 0.05


def stamp_seconds(header: Any, fallback_ns: int) -> float:
    """A header's stamp in seconds; the bag's receive time where the stamp is zero."""
    sec, nsec = int(header.stamp.sec), int(header.stamp.nanosec)
    if sec == 0 and nsec == 0:
        return fallback_ns * 1e-9
    return sec + nsec * 1e-9


def pair_by_stamp(
    stream: Iterable[tuple[str, float, A | B]], max_dt: float
) -> Iterator[tuple[float, A, B | None]]:
    """Pair each depth item with the colour item of the nearest stamp within ``max_dt``.

    ``stream`` yields ``("depth" | "rgb", stamp, item)`` in (about) increasing stamp order, as
    a bag stores them; yields ``(depth stamp, depth item, rgb item or None)`` in depth order,
    holding only the few images of the pairing window in memory."""
    rgbs: deque[tuple[float, Any]] = deque()
    depths: deque[tuple[float, Any]] = deque()
    newest_rgb = newest_depth = -math.inf

    def settle(stamp: float, item: Any) -> tuple[float, Any, Any]:
        best = min(rgbs, key=lambda r: abs(r[0] - stamp), default=None)
        if best is None or abs(best[0] - stamp) > max_dt:
            return stamp, item, None
        return stamp, item, best[1]

    for kind, stamp, item in stream:
        if kind == "depth":
            depths.append((stamp, item))
            newest_depth = max(newest_depth, stamp)
        else:
            rgbs.append((stamp, item))
            newest_rgb = max(newest_rgb, stamp)
        # a depth whose window has closed (a colour image after it) is paired now
        while depths and newest_rgb > depths[0][0] + max_dt:
            yield settle(*depths.popleft())
        # colour images too old for any waiting or later depth image are let go
        oldest = depths[0][0] if depths else newest_depth
        while rgbs and rgbs[0][0] < oldest - max_dt:
            rgbs.popleft()
    while depths:
        yield settle(*depths.popleft())


def bag_path(path: Path) -> Path:
    """The path rosbags opens: a ROS 1 ``.bag`` file or a ROS 2 bag directory (given also as
    its ``metadata.yaml``, ``.db3`` or ``.mcap`` file)."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag {path}: no such file or directory")
    if path.is_file() and path.suffix != ".bag":
        if (path.parent / "metadata.yaml").is_file():
            return path.parent
        raise BagError(f"bag {path}: neither a ROS 1 .bag file nor a ROS 2 bag directory")
    return path


class BagFrames:
    """The RgbdFrames of a bag, in order (``with BagFrames(path, config) as frames: for f in
    frames``). Depth images without a colour image within ``max_dt`` and images without a
    pose in the tf tree are skipped and counted in ``skipped``."""

    def __init__(self, path: Path, config: BagReplayConfig) -> None:
        self.path = bag_path(path)
        self.config = config
        self.skipped: Counter[str] = Counter()
        self.tree: TransformTree | None = None
        self.camera_frame = ""
        self.world_frame = ""
        self.intrinsics: CameraIntrinsics | None = None
        self._reader: Any = None
        self._info: Any = None

    # -- opening: everything that can be checked before the first frame ----------------------

    def __enter__(self) -> BagFrames:
        from rosbags.highlevel import AnyReader, AnyReaderError
        from rosbags.typesys import Stores, get_typestore

        # ROS 2 bags before Iron carry no message definitions: Humble's are the fallback
        fallback = get_typestore(Stores.ROS2_HUMBLE)
        try:
            self._reader = AnyReader([self.path], default_typestore=fallback)
            self._reader.open()
        except (AnyReaderError, OSError) as e:
            raise BagError(f"bag {self.path}: cannot be read ({e})") from None
        try:
            self._check_topics()
            self._info = self._camera_info()
            if self.config.tf:
                self._load_tf()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    def _connections(self, topic: str) -> list[Any]:
        return [c for c in self._reader.connections if c.topic == topic]

    def _check_topics(self) -> None:
        c = self.config
        topics = self._reader.topics
        listing = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items()))
        images = (IMAGE_TYPE, COMPRESSED_TYPE)
        wanted = {"--rgb": (c.rgb, images), "--depth": (c.depth, images),
                  "--camera-info": (c.camera_info, (INFO_TYPE,))}  # fmt: skip
        for flag, (topic, msgtypes) in wanted.items():
            if topic not in topics:
                raise BagError(f"{flag} topic {topic} is not in the bag (topics: {listing})")
            have = topics[topic].msgtype
            if have not in msgtypes:
                raise BagError(f"{flag} topic {topic} carries {have}, not {' or '.join(msgtypes)}")
            if topics[topic].msgcount == 0:
                raise BagError(f"{flag} topic {topic} has no messages")
        if c.rgb == c.depth:
            raise BagError(f"--rgb and --depth are the same topic {c.rgb}")

    def _camera_info(self) -> Any:
        conns = self._connections(self.config.camera_info)
        for conn, _t, raw in self._reader.messages(connections=conns):
            return self._reader.deserialize(raw, conn.msgtype)
        raise BagError(f"--camera-info topic {self.config.camera_info} has no messages")

    def _load_tf(self) -> None:
        conns = [c for c in self._reader.connections if c.topic in TF_TOPICS]
        if not conns:
            raise BagError("--tf: the bag has no /tf or /tf_static topic (use --pose instead)")
        self.camera_frame = frame_name(self._info.header.frame_id)
        if not self.camera_frame:
            raise BagError(f"--tf: the camera_info on {self.config.camera_info} names no frame_id")
        tree = TransformTree(self.config.tf_tolerance)
        for conn, t_ns, raw in self._reader.messages(connections=conns):
            message = self._reader.deserialize(raw, conn.msgtype)
            for tf in message.transforms:
                p, q = tf.transform.translation, tf.transform.rotation
                stamp = stamp_seconds(tf.header, t_ns)
                static = conn.topic == "/tf_static"
                tree.add(tf.header.frame_id, tf.child_frame_id, stamp,
                         (p.x, p.y, p.z), (q.x, q.y, q.z, q.w), static)  # fmt: skip
        try:
            chain = tree.chain(self.camera_frame, self.config.world_frame)
        except TfError as e:
            raise BagError(f"--tf: {e}") from None
        self.tree, self.world_frame = tree, chain[-1]
        log.info("camera pose from tf: %s", " → ".join(reversed(chain)))
        roots = sorted(tree.roots)
        if len(roots) > 1 and not self.config.world_frame:
            log.warning("the bag's tf is %d separate trees (roots: %s): the camera's world is "
                        "%s", len(roots), ", ".join(roots), chain[-1])  # fmt: skip

    # -- frames --------------------------------------------------------------------------------

    @property
    def expected(self) -> int:
        """Depth images in the bag: the most frames a replay can give."""
        return self._reader.topics[self.config.depth].msgcount

    def pose_at(self, stamp: float) -> np.ndarray:
        if self.tree is None:
            return self.config.T_world_camera
        return self.tree.lookup(self.camera_frame, stamp, self.world_frame)

    def _intrinsics(self, width: int, height: int) -> CameraIntrinsics:
        if self.intrinsics is None:
            info = self._info
            w, h = int(info.width), int(info.height)
            if (w, h) != (0, 0) and (w, h) != (width, height):
                raise BagError(
                    f"camera_info on {self.config.camera_info} is for {w}×{h} images, "
                    f"the depth images are {width}×{height}"
                )
            K = getattr(info, "K", None)
            K = info.k if K is None else K
            D = getattr(info, "D", None)
            D = info.d if D is None else D
            try:
                self.intrinsics = intrinsics_from_camera_info(K, width, height)
            except ConversionError as e:
                raise BagError(f"{self.config.camera_info}: {e}") from None
            if has_distortion(D):
                coefficients = np.round(np.asarray(D, float), 4).tolist()
                log.warning("camera_info has lens distortion %s: the images are used as they "
                            "are, unrectified", coefficients)  # fmt: skip
        return self.intrinsics

    @staticmethod
    def _image(
        flag: str,
        topic: str,
        msg: Any,
        convert: Callable[[np.ndarray, str], np.ndarray],
        compressed: Callable[[str, Any], np.ndarray],
    ):
        """A message's pixels through ``convert`` (Image) or ``compressed`` (CompressedImage,
        its ``format`` and data); a message that cannot be read names its topic and why."""
        try:
            if hasattr(msg, "format"):  # sensor_msgs/CompressedImage
                return compressed(str(msg.format), msg.data)
            pixels = image_array(msg.encoding, int(msg.height), int(msg.width), int(msg.step),
                                 msg.data, bool(msg.is_bigendian))  # fmt: skip
            return convert(pixels, msg.encoding)
        except ConversionError as e:
            raise BagError(f"{flag} topic {topic}: {e}") from None

    def frame(
        self, seq: int, stamp: float, depth_msg: Any, rgb_msg: Any, T_world_camera: np.ndarray
    ) -> RgbdFrame:
        """The RgbdFrame of one pair of images at ``stamp`` (the depth image's)."""
        c = self.config
        depth = self._image(
            "--depth", c.depth, depth_msg,
            lambda pixels, encoding: depth_from_image(pixels, encoding, c.depth_scale),
            lambda fmt, data: depth_from_compressed(fmt, data, c.depth_scale),
        )  # fmt: skip
        rgb = self._image("--rgb", c.rgb, rgb_msg, rgb_from_image, rgb_from_compressed)
        h, w = depth.shape
        if rgb.shape[:2] != (h, w):
            raise BagError(
                f"colour images are {rgb.shape[1]}×{rgb.shape[0]}, depth images {w}×{h}: "
                "replay needs depth registered to the colour camera (same size)"
            )
        return RgbdFrame(
            seq=seq,
            stamp=stamp,
            camera=c.camera,
            intrinsics=self._intrinsics(w, h),
            rgb=rgb,
            depth=depth,
            T_world_camera=T_world_camera,
            depth_min=c.depth_min,
            depth_max=c.depth_max,
        )

    def _images(self) -> Iterator[tuple[str, float, Any]]:
        c, reader = self.config, self._reader
        conns = self._connections(c.rgb) + self._connections(c.depth)
        start = reader.start_time + int(c.start * 1e9) if c.start > 0 else None
        for conn, t_ns, raw in reader.messages(connections=conns, start=start):
            msg = reader.deserialize(raw, conn.msgtype)
            kind = "depth" if conn.topic == c.depth else "rgb"
            yield kind, stamp_seconds(msg.header, t_ns), msg

    def __iter__(self) -> Iterator[RgbdFrame]:
        if self._reader is None:
            raise RuntimeError("BagFrames is iterated inside its with block")
        seq = 0
        for stamp, depth_msg, rgb_msg in pair_by_stamp(self._images(), self.config.max_dt):
            if rgb_msg is None:
                self.skipped["unpaired"] += 1
                continue
            try:
                T = self.pose_at(stamp)
            except ExtrapolationError as e:
                if not self.skipped["no_pose"]:
                    log.warning("frames without a camera pose in tf are skipped: %s", e)
                self.skipped["no_pose"] += 1
                continue
            yield self.frame(seq, stamp, depth_msg, rgb_msg, T)
            seq += 1
            if self.config.limit and seq >= self.config.limit:
                return
