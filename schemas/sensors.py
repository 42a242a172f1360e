"""What the robot (the sim, a replay, or hardware) publishes: images, IMU, joints, odometry."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from schemas.arrays import Array, Dim
from schemas.base import Model, Stamped
from schemas.types import Finite, Pose, Quat, Vec3

#: Largest image side accepted on the wire; bigger frames are refused as oversized.
MAX_IMAGE_SIDE = 4096


class CameraIntrinsics(Model):
    """Pinhole intrinsics in pixels: u = fx·x/z + cx, v = fy·y/z + cy (optical frame)."""

    width: int = Field(gt=0, le=MAX_IMAGE_SIDE)
    height: int = Field(gt=0, le=MAX_IMAGE_SIDE)
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width: int, height: int, fovy_deg: float) -> CameraIntrinsics:
        """Square pixels, principal point at the image centre, vertical field of view in degrees."""
        f = 0.5 * height / np.tan(np.deg2rad(fovy_deg) / 2)
        return cls(width=width, height=height, fx=f, fy=f, cx=(width - 1) / 2, cy=(height - 1) / 2)

    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


class RgbdFrame(Stamped):
    """One camera frame. ``depth`` is metres along the optical axis, 0 where there is no return;
    cameras without depth (ARMAR-III's eyes) leave it out."""

    camera: str = Field(min_length=1, description="camera name, e.g. head_rgbd or left_foveal")
    intrinsics: CameraIntrinsics
    rgb: Annotated[np.ndarray, Array("uint8", ("h", "w", 3))] | None = None
    depth: Annotated[np.ndarray, Array("float32", ("h", "w"), description="metres")] | None = None
    T_world_camera: Pose = Field(
        description="the camera's pose as the robot believes it: its kinematics of the "
        "measured joints (joint_positions) with the platform where its odometry says"
    )
    depth_min: float = Field(0.0, ge=0, description="closest valid depth of the sensor, m")
    depth_max: float = Field(0.0, ge=0, description="farthest valid depth of the sensor, m")
    joint_names: Annotated[list[str], Dim("j")] = Field(
        default_factory=list,
        description="the robot's joints at capture (with joint_positions): perception masks "
        "the robot's own body with them",
    )
    joint_positions: Annotated[np.ndarray, Array("float64", ("j",)), Finite()] | None = None

    @model_validator(mode="after")
    def _consistent(self) -> RgbdFrame:
        image = self.rgb if self.rgb is not None else self.depth
        if image is None:
            raise ValueError("a frame carries rgb, depth, or both")
        h, w = image.shape[:2]
        if self.joint_names and self.joint_positions is None:
            raise ValueError("joint_names without joint_positions")
        if (w, h) != (self.intrinsics.width, self.intrinsics.height):
            raise ValueError(
                f"image is {w}×{h} but intrinsics say "
                f"{self.intrinsics.width}×{self.intrinsics.height}"
            )
        return self


class CloudFrame(Stamped):
    """A world-frame point cloud to perceive as one observation (sensors/cloud/<camera>): in
    ``pc`` / ``pc+sg`` fusion the scene memory's registered cloud of the roi, every view so far
    merged and voxel-downsampled (thesis 3.3.1), published after each integrated frame. Its
    pose and intrinsics are those of that frame (the observation's, for fusion and
    affordances); ``viewpoints`` says where each point was seen from (its normal faces it)."""

    camera: str = Field(min_length=1, description="the name observations of it carry")
    frame_seq: int = Field(ge=0, description="seq of the RgbdFrame that completed the cloud")
    T_world_camera: Pose
    intrinsics: CameraIntrinsics
    points: Annotated[np.ndarray, Array("float32", ("n", 3), description="world, m")]
    viewpoints: Annotated[
        np.ndarray, Array("float32", ("n", 3), description="optical centre that saw each point")
    ]
    colours: Annotated[np.ndarray, Array("uint8", ("n", 3))] | None = None
    voxel_size: float = Field(0.0, ge=0, description="downsampling voxel, 0 if none")
    depth_max: float = Field(0.0, ge=0, description="farthest valid depth of the sensor, m")


class ImuSample(Stamped):
    """Head IMU: gyro (rad/s) and accelerometer (specific force, m/s²) in the IMU frame, plus the
    IMU frame's orientation in the world."""

    frame: str = "head_imu"
    angular_velocity: Vec3
    linear_acceleration: Vec3
    orientation: Quat


class JointState(Stamped):
    """Measured joint positions (rad or m) and velocities, in the order of ``names``."""

    names: Annotated[list[str], Dim("n")]
    position: Annotated[np.ndarray, Array("float64", ("n",)), Finite()]
    velocity: Annotated[np.ndarray, Array("float64", ("n",)), Finite()]


class BasePose(Stamped):
    """Platform odometry in the world: pose (x, y, yaw) and velocity, plus the goal being driven."""

    x: float
    y: float
    yaw: float
    v_x: float = 0.0
    v_y: float = 0.0
    v_yaw: float = 0.0
    goal_id: str = ""
    goal_status: Literal["idle", "moving", "reached", "aborted"] = "idle"
