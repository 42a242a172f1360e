"""A recording's frames as RgbdFrames: images decoded, depth in metres (holes 0), the pose the
dataset gives moved by ``T_up`` (the world turned so that z is up and the floor at z = 0:
``gravity.py``), or a fixed pose where the dataset has none; with ``drift``, given an
odometry-like drift after that (``drift.py``)."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from schemas import CameraIntrinsics, RgbdFrame
from services.adapters.dataset.drift import Drift, drifted
from services.adapters.dataset.formats import DatasetError, Recording


def load_colour(path: Path) -> np.ndarray:
    """(h, w, 3) uint8 RGB."""
    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"), np.uint8)
    except OSError as e:
        raise DatasetError(f"{path}: not a colour image ({e})") from None


def load_depth(path: Path, scale: float, invalid: tuple[int, ...] = ()) -> np.ndarray:
    """(h, w) float32 metres from a 16-bit depth image; 0 and ``invalid`` values are holes."""
    try:
        with Image.open(path) as im:
            raw = np.asarray(im)
    except OSError as e:
        raise DatasetError(f"{path}: not a depth image ({e})") from None
    if raw.ndim != 2 or raw.dtype.kind not in "iu" or raw.dtype.itemsize < 2:
        raise DatasetError(
            f"{path}: depth must be a 16-bit single-channel image, not {raw.dtype} {raw.shape}"
        )
    depth = raw.astype(np.float32) * np.float32(scale)
    holes = raw == 0
    for v in invalid:
        holes |= raw == v
    depth[holes] = 0.0
    return depth


@dataclass
class DatasetFrames:
    """Iterate a recording's frames (from ``start`` s, every ``every``-th, at most ``limit``)."""

    recording: Recording
    camera: str = "head_rgbd"
    #: world → the frame published in: z up, the floor at z = 0 (identity: the dataset's)
    T_up: np.ndarray = field(default_factory=lambda: np.eye(4))
    #: the camera's pose where the dataset has none
    T_fixed: np.ndarray = field(default_factory=lambda: np.eye(4))
    start: float = 0.0
    every: int = 1
    limit: int = 0
    colour: bool = True
    #: an odometry-like drift given to the k-th played frame's pose (None: the poses as they are)
    drift: Drift | None = None

    def indices(self) -> list[int]:
        r = self.recording
        t0 = r.stamps[0]
        chosen = [i for i in range(len(r)) if r.stamps[i] - t0 >= self.start - 1e-9]
        chosen = chosen[:: max(1, self.every)]
        return chosen[: self.limit] if self.limit else chosen

    def pose(self, i: int) -> np.ndarray:
        """Frame ``i``'s pose in the published world (z up), without drift."""
        r = self.recording
        T = r.poses[i] if r.poses is not None else self.T_fixed
        return self.T_up @ T

    def published_pose(self, i: int, seq: int) -> np.ndarray:
        """What frame ``i``, played as the ``seq``-th, carries: its pose with ``seq`` frames of
        drift, turned about the first played camera's position (``drift.py``)."""
        T = self.pose(i)
        if self.drift is None or seq == 0:
            return T
        pivot = self.pose(self.indices()[0])[:3, 3]
        return drifted(T, seq, self.drift, pivot)

    def frame(self, i: int, seq: int) -> RgbdFrame:
        r = self.recording
        depth = load_depth(r.depth[i], r.depth_scale, r.invalid_depth)
        h, w = depth.shape
        rgb = load_colour(r.colour[i]) if self.colour else None
        if rgb is not None and rgb.shape[:2] != (h, w):
            raise DatasetError(
                f"{r.colour[i].name} is {rgb.shape[1]}×{rgb.shape[0]}, its depth {w}×{h}: colour "
                "and depth must be registered to one camera of one size (--no-colour plays the "
                "depth alone)"
            )
        k = r.intrinsics
        if k.width and (k.width, k.height) != (w, h):
            raise DatasetError(
                f"{r.depth[i].name} is {w}×{h}, the intrinsics are for {k.width}×{k.height}"
            )
        return RgbdFrame(
            seq=seq,
            stamp=float(r.stamps[i] - r.stamps[0]),
            camera=self.camera,
            intrinsics=CameraIntrinsics(width=w, height=h, fx=k.fx, fy=k.fy, cx=k.cx, cy=k.cy),
            rgb=rgb,
            depth=depth,
            T_world_camera=self.published_pose(i, seq),
        )

    def __iter__(self) -> Iterator[RgbdFrame]:
        for seq, i in enumerate(self.indices()):
            yield self.frame(i, seq)
