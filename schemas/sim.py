"""The simulator's control and ground truth (sim/control, sim/ground_truth)."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from schemas.arrays import Array
from schemas.base import Message, Model, Stamped
from schemas.types import Pose, Vec3


class GroundTruthObject(Model):
    """A body of the scene: its kind (the geom type, ``compound`` for several geoms), pose and
    the full side lengths of its bounding box in its own frame."""

    name: str
    kind: Literal["box", "cylinder", "sphere", "plane", "compound"]
    pose: Pose
    size: Annotated[np.ndarray, Array("float64", (3,))]
    static: bool = False


class GroundTruth(Stamped):
    """The truth of the current scene: objects, support graph (direct edges and transitive
    closure), and optionally the per-pixel segmentation of the current frame of ``camera``;
    the true camera pose and the odometry's error (version 2)."""

    VERSION: ClassVar[int] = 2

    scene: str
    robot: str
    objects: list[GroundTruthObject]
    support_edges: list[tuple[str, str]] = Field(description="(supporter, supported), in contact")
    support_closure: list[tuple[str, str]]
    camera: str = ""
    segmentation: Annotated[np.ndarray, Array("int32", ("h", "w"))] | None = Field(
        None, description="index into labels per pixel, -1 where no scene body is seen"
    )
    labels: list[str] = Field(default_factory=list)
    roi_min: Vec3 | None = Field(None, description="the scene's region of interest, if any")
    roi_max: Vec3 | None = None
    T_world_camera: Pose | None = Field(
        None, description="the true pose of the camera (``camera``, or the robot's first) now"
    )
    T_world_odom: Pose | None = Field(
        None,
        description="what the robot's odometry gets wrong: T_believed = T_world_odom · T_true "
        "for the platform (for a frame's camera, up to the encoders' error in the joints "
        "between; None with the sensor models off)",
    )


class GroundTruthQuery(Message):
    """Query payload of sim/ground_truth: which camera to segment (default: the robot's first)
    and what to compute."""

    camera: str = ""
    segmentation: bool = True
    support: bool = True


SimOp = Literal["reset", "step", "render", "pause", "resume", "set_disturbance", "status"]


class SimControl(Message):
    """A request on sim/control. ``reset`` takes scene/robot/seed, ``step`` takes n,
    ``set_disturbance`` takes joint/amplitude (deg/s)/frequency (Hz)."""

    op: SimOp
    scene: str | None = None
    robot: str | None = None
    seed: int | None = None
    n: int = Field(
        1,
        ge=1,
        le=10_000,
        description="physics steps of one step request: at most 10,000 (10 s of sim time at "
        "1 ms), so that no query holds the sim for long",
    )
    joint: str | None = None
    amplitude: float = 0.0
    frequency: float = Field(0.0, ge=0)

    @model_validator(mode="after")
    def _arguments(self) -> SimControl:
        if self.op == "set_disturbance" and not self.joint:
            raise ValueError("set_disturbance needs a joint")
        return self


class SimStatus(Message):
    """The reply to every SimControl request."""

    ok: bool
    error: str = ""
    mode: Literal["realtime", "lockstep", "replay"]
    scene: str
    robot: str
    sim_time: float = Field(ge=0)
    steps: int = Field(ge=0)
    paused: bool = False
    #: the seq of the newest message each state stream ("imu", "joints", "base") has put on the
    #: wire since the reset: a lockstep driver waits for these before it reads the streams
    published: dict[str, int] = Field(default_factory=dict)
    #: the seq of the newest command the sim applied on each command stream ("base", "head",
    #: "arm") since the reset: a lockstep driver waits for a planner's commands before it steps
    #: (they come by another route than its own request, and could land a step late)
    applied: dict[str, int] = Field(default_factory=dict)
