"""Pure conversions from ROS sensor messages to the fields of an RgbdFrame: image buffers to
arrays, depth to metres, CameraInfo to intrinsics, ROS transforms and poses to 4×4 matrices.

Nothing here imports ROS, rosbags or Zenoh: the arguments are plain values and arrays, so any
source of ROS-style data (a bag, a live camera driver) can share them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from schemas import CameraIntrinsics
from services.adapters.camera import (  # noqa: F401 - this module's users take them from here
    R_BODY_OPTICAL,
    depth_to_metres,
    fixed_camera_pose,
    optical_pose_from_body,
)

#: ROS image encodings understood: numpy dtype of one channel and the channel count.
IMAGE_ENCODINGS: dict[str, tuple[str, int]] = {
    "rgb8": ("u1", 3),
    "bgr8": ("u1", 3),
    "rgba8": ("u1", 4),
    "bgra8": ("u1", 4),
    "mono8": ("u1", 1),
    "8UC1": ("u1", 1),
    "16UC1": ("u2", 1),
    "mono16": ("u2", 1),
    "32FC1": ("f4", 1),
}
COLOUR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8UC1")
#: depth encodings (REP 118): 16-bit unsigned in millimetres, 32-bit float in metres
DEPTH_ENCODINGS = ("16UC1", "mono16", "32FC1")


class ConversionError(ValueError):
    """A message that cannot become part of an RgbdFrame (its encoding, size, calibration)."""


def image_array(
    encoding: str,
    height: int,
    width: int,
    step: int,
    data: bytes | np.ndarray,
    bigendian: bool = False,
) -> np.ndarray:
    """The pixels of a ROS ``sensor_msgs/Image`` as (h, w) or (h, w, c), native byte order
    (rows may be padded: ``step`` bytes per row)."""
    if encoding not in IMAGE_ENCODINGS:
        raise ConversionError(
            f"image encoding {encoding!r} is not supported "
            f"(supported: {', '.join(IMAGE_ENCODINGS)})"
        )
    kind, channels = IMAGE_ENCODINGS[encoding]
    dtype = np.dtype(kind).newbyteorder(">" if bigendian else "<")
    row = width * channels * dtype.itemsize
    buffer = np.frombuffer(data, np.uint8) if not isinstance(data, np.ndarray) else data
    buffer = buffer.reshape(-1).view(np.uint8)
    if step < row or buffer.size < step * height:
        raise ConversionError(
            f"{encoding} image of {width}×{height} needs {row} bytes a row and "
            f"{row * height} in all; the message has step {step} and {buffer.size} bytes"
        )
    rows = buffer[: step * height].reshape(height, step)[:, :row]
    pixels = np.ascontiguousarray(rows).view(dtype).astype(dtype.newbyteorder("="), copy=False)
    return pixels.reshape((height, width, channels) if channels > 1 else (height, width))


def rgb_from_image(pixels: np.ndarray, encoding: str) -> np.ndarray:
    """(h, w, 3) uint8 RGB from decoded pixels of a colour or grey encoding."""
    if encoding not in COLOUR_ENCODINGS:
        raise ConversionError(
            f"colour image encoding {encoding!r} is not supported "
            f"(supported: {', '.join(COLOUR_ENCODINGS)})"
        )
    if pixels.ndim == 2:
        return np.repeat(pixels[:, :, None], 3, axis=2)
    rgb = pixels[:, :, :3]
    if encoding.startswith("bgr"):
        rgb = rgb[:, :, ::-1]
    return np.ascontiguousarray(rgb, dtype=np.uint8)


def depth_from_image(pixels: np.ndarray, encoding: str, scale: float | None = None) -> np.ndarray:
    """Metres from a decoded depth image of a ROS depth encoding (16UC1 mm, 32FC1 m)."""
    if encoding not in DEPTH_ENCODINGS:
        raise ConversionError(
            f"depth image encoding {encoding!r} is not supported "
            f"(supported: {', '.join(DEPTH_ENCODINGS)})"
        )
    return depth_to_metres(pixels, scale)


#: the first bytes of a PNG; compressedDepth data starts with a 12-byte header before them
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: compressed_depth_image_transport's ConfigHeader: format (int32), depthQuantA, depthQuantB
COMPRESSED_DEPTH_HEADER = 12


def _decode_image(data: bytes, what: str):
    import io

    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(io.BytesIO(data)) as im:
            im.load()
            return im.copy()
    except (UnidentifiedImageError, OSError) as e:
        raise ConversionError(f"{what}: the data is no image PIL can read ({e})") from None


def rgb_from_compressed(fmt: str, data: bytes | np.ndarray) -> np.ndarray:
    """(h, w, 3) uint8 RGB from a ``sensor_msgs/CompressedImage`` (``format`` "jpeg", "png",
    or image_transport's "bgr8; jpeg compressed bgr8"). The codec's colour order is RGB
    whatever the format names: JPEG and PNG store RGB, image_transport converts on encoding."""
    kind = fmt.split(";")[-1].strip().lower()
    if "compresseddepth" in fmt.lower():
        raise ConversionError(f"colour image format {fmt!r} is a compressedDepth depth image")
    if not any(k in kind for k in ("jpeg", "jpg", "png")):
        raise ConversionError(f"compressed colour format {fmt!r} is not supported (jpeg, png)")
    im = _decode_image(bytes(data), f"compressed colour ({fmt!r})")
    return np.asarray(im.convert("RGB"), np.uint8)


def depth_from_compressed(fmt: str, data: bytes | np.ndarray, scale: float | None = None
                          ) -> np.ndarray:  # fmt: skip
    """Metres from a ``compressedDepth`` CompressedImage (``format`` "16UC1; compressedDepth
    png" or "32FC1; compressedDepth png"): a 12-byte header (format, depthQuantA, depthQuantB)
    then a 16-bit PNG: millimetres for 16UC1; for 32FC1 inverse depth, d = A / (v − B), 0 none
    (compressed_depth_image_transport). A plain PNG of 16-bit mm is taken too."""
    raw = bytes(data)
    encoding = fmt.split(";")[0].strip()
    if encoding not in ("16UC1", "32FC1"):
        raise ConversionError(
            f"compressed depth format {fmt!r}: the depth encoding must be 16UC1 or 32FC1"
        )
    if "png" not in fmt.lower() and not raw.startswith(PNG_SIGNATURE):
        raise ConversionError(f"compressed depth format {fmt!r} is not supported (png only)")
    header = b""
    if not raw.startswith(PNG_SIGNATURE):
        header, raw = raw[:COMPRESSED_DEPTH_HEADER], raw[COMPRESSED_DEPTH_HEADER:]
    pixels = np.asarray(_decode_image(raw, f"compressed depth ({fmt!r})"))
    if pixels.ndim != 2 or pixels.dtype.itemsize != 2:
        raise ConversionError(
            f"compressed depth ({fmt!r}) holds a {pixels.dtype} {pixels.shape} image, "
            "not 16-bit single-channel"
        )
    values = pixels.astype(np.uint16)
    if encoding == "16UC1":
        return depth_to_metres(values, scale)
    if len(header) != COMPRESSED_DEPTH_HEADER:
        raise ConversionError(f"compressed 32FC1 depth ({fmt!r}) has no quantisation header")
    a, b = np.frombuffer(header[4:12], "<f4").astype(np.float64)
    v = values.astype(np.float64)
    depth = np.zeros(values.shape, np.float32)
    ok = (values > 0) & (v - b > 0)
    depth[ok] = (a / (v[ok] - b)).astype(np.float32)
    return depth


def intrinsics_from_camera_info(K: Sequence[float], width: int, height: int) -> CameraIntrinsics:
    """Pinhole intrinsics from a CameraInfo's 3×3 ``K`` (row major) for an image of
    width × height. Lens distortion is not modelled (see ``has_distortion``)."""
    k = np.asarray(K, float).reshape(-1)
    if k.size != 9:
        raise ConversionError(f"camera_info K has {k.size} values, not 9")
    fx, fy, cx, cy = k[0], k[4], k[2], k[5]
    if not (fx > 0 and fy > 0 and np.isfinite(k).all()):
        raise ConversionError(
            f"camera_info K has no focal length (fx={fx}, fy={fy}): the camera is not calibrated"
        )
    return CameraIntrinsics(width=width, height=height, fx=fx, fy=fy, cx=cx, cy=cy)


def has_distortion(D: Sequence[float]) -> bool:
    """Whether a CameraInfo's distortion coefficients are not all zero (unrectified images)."""
    return bool(np.any(np.abs(np.asarray(D, float)) > 1e-12))


def quaternion_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """Rotation matrix of a ROS quaternion (x, y, z, w; normalised here)."""
    q = np.array([w, x, y, z], float)
    n = np.linalg.norm(q)
    if not n > 0:
        raise ConversionError("zero quaternion")
    w, x, y, z = q / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def transform_matrix(translation: Sequence[float], rotation_xyzw: Sequence[float]) -> np.ndarray:
    """4×4 pose of a ROS ``geometry_msgs/Transform`` (translation, quaternion x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3] = quaternion_matrix(*rotation_xyzw)
    T[:3, 3] = translation
    return T
