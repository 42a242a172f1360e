"""What the sim needs to know about each robot beyond its MJCF: cameras, limits, home pose."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from services.common.robots import JOINT_SPEED
from services.sim.sensors import SensorSpec

ROBOTS_DIR = Path(__file__).parent / "robots"

#: Joint names of the planar base, in the order (x, y, yaw).
BASE_JOINTS = ("base_x", "base_y", "base_yaw")


@dataclass(frozen=True)
class CameraInfo:
    """A camera of the robot. ``depth_range`` is (min, max) metres for RGB-D cameras, None for
    colour-only ones."""

    name: str
    depth_range: tuple[float, float] | None = None


@dataclass(frozen=True)
class RobotInfo:
    name: str
    cameras: tuple[CameraInfo, ...]
    #: the camera published by default
    default_cameras: tuple[str, ...]
    #: maximum platform speeds (m/s, rad/s) and accelerations (m/s², rad/s²)
    vel_lin: float
    vel_rot: float
    acc_lin: float
    acc_rot: float
    footprint_radius: float
    #: maximum joint speeds for position commands (rad/s or m/s)
    joint_speed: dict[str, float] = field(default_factory=dict)
    #: joint positions at start
    home: dict[str, float] = field(default_factory=dict)
    #: what its IMU, encoders, cameras and odometry get wrong (used with the sim's ``sensors``)
    sensors: SensorSpec = field(default_factory=SensorSpec)

    @property
    def mjcf(self) -> Path:
        return ROBOTS_DIR / f"{self.name}.xml"

    def camera(self, name: str) -> CameraInfo:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(f"{self.name} has no camera {name!r} (has {[c.name for c in self.cameras]})")


ARMAR6 = RobotInfo(
    name="armar6",
    cameras=(CameraInfo("head_rgbd", depth_range=(0.35, 8.0)),),
    default_cameras=("head_rgbd",),
    vel_lin=0.5,
    vel_rot=1.0,
    acc_lin=0.5,
    acc_rot=1.0,
    footprint_radius=0.45,
    joint_speed=JOINT_SPEED["armar6"],
    home={"torso_lift": 0.2, "neck_yaw": 0.0, "neck_pitch": 0.35},
)

ARMAR3 = RobotInfo(
    name="armar3",
    cameras=(
        CameraInfo("left_peripheral"),
        CameraInfo("left_foveal"),
        CameraInfo("right_peripheral"),
        CameraInfo("right_foveal"),
    ),
    default_cameras=("left_peripheral",),
    vel_lin=0.5,
    vel_rot=1.0,
    acc_lin=0.5,
    acc_rot=1.0,
    footprint_radius=0.4,
    joint_speed=JOINT_SPEED["armar3"],
    home={
        "neck_lower_pitch": 0.2,
        "neck_upper_pitch": 0.15,
        # the arms at rest: upper arms down, forearms forward, grippers open
        **{f"{s}_shoulder_pitch": -0.3 for s in "lr"},
        **{f"{s}_elbow": -1.3 for s in "lr"},
        "l_shoulder_roll": 0.15,
        "r_shoulder_roll": -0.15,
    },
)

ROBOTS = {r.name: r for r in (ARMAR6, ARMAR3)}
