"""Deterministic test streams: message i of a stream is the same in every process."""

from __future__ import annotations

import numpy as np

from schemas import CameraIntrinsics, ImuSample, RgbdFrame


def imu_sample(i: int) -> ImuSample:
    rng = np.random.default_rng(i)
    q = rng.normal(size=4)
    return ImuSample(
        seq=i,
        stamp=i * 1e-3,
        angular_velocity=rng.normal(size=3),
        linear_acceleration=rng.normal(size=3) + np.array([0.0, 0.0, 9.81]),
        orientation=q / np.linalg.norm(q),
    )


def rgbd_frame(i: int, width: int = 640, height: int = 480) -> RgbdFrame:
    rng = np.random.default_rng(10_000 + i)
    T = np.eye(4)
    T[:3, 3] = rng.normal(size=3)
    return RgbdFrame(
        seq=i,
        stamp=i / 30,
        camera="head_rgbd",
        intrinsics=CameraIntrinsics.from_fov(width, height, 45.0),
        rgb=rng.integers(0, 256, (height, width, 3), dtype=np.uint8),
        depth=rng.uniform(0.35, 3.0, (height, width)).astype(np.float32),
        T_world_camera=T,
        depth_min=0.35,
        depth_max=3.0,
    )
