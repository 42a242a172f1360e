"""What the robot obeys: platform goals and velocities, head joint commands, arm commands."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from schemas.arrays import Array, Dim
from schemas.base import Stamped
from schemas.types import Finite, Pose


class BaseGoal(Stamped):
    """Drive the holonomic platform to (x, y, yaw) in the world, through ``path`` if given
    (waypoints (x, y, yaw) before the goal), within the platform's velocity limits."""

    goal_id: str = Field("", description="echoed in BasePose.goal_id while this goal is driven")
    x: float
    y: float
    yaw: float
    path: Annotated[np.ndarray, Array("float64", (None, 3), max_rows=10_000), Finite()] | None = (
        None
    )


class BaseVelocity(Stamped):
    """Platform velocity in the base frame (m/s, rad/s); it stops after ``timeout`` s without a
    newer command."""

    v_x: float
    v_y: float = 0.0
    v_yaw: float = 0.0
    timeout: float = Field(0.5, gt=0)


class HeadCommand(Stamped):
    """Positions (rad) or velocities (rad/s) for the named head/eye joints; others keep their
    command. Values are clamped to the joint limits by the robot."""

    names: Annotated[list[str], Dim("n")]
    mode: Literal["position", "velocity"]
    values: Annotated[np.ndarray, Array("float64", ("n",)), Finite()]
    source: str = Field("", description="who commands: gaze, nbv, manual …")
    trigger_stamp: float | None = Field(
        None, description="stamp of the input that caused this command (latency tracing)"
    )


class ArmCommand(Stamped):
    """One arm of the robot: joint velocities (rad/s; a joint stops after the robot's command
    timeout without a newer one) or positions (rad) for named arm joints, or a Cartesian goal
    for the hand's grasp frame (``goal``: T_platform_grasp, z the approach direction, x the
    fingers' closing axis; the robot resolves it by inverse kinematics); and/or the gripper
    (0 open … 1 closed, with the fingers' force limit)."""

    arm: Literal["left", "right"]
    mode: Literal["velocity", "position", "cartesian", "gripper"]
    names: Annotated[list[str], Dim("n")] = Field(default_factory=list)
    values: Annotated[np.ndarray, Array("float64", ("n",)), Finite()] | None = None
    goal: Pose | None = None
    gripper: float | None = Field(None, ge=0.0, le=1.0)
    source: str = Field("", description="who commands: servo, manual …")

    @model_validator(mode="after")
    def _complete(self) -> ArmCommand:
        if self.mode in ("velocity", "position") and (self.values is None or not self.names):
            raise ValueError(f"mode {self.mode!r} needs names and values")
        if self.mode == "cartesian" and self.goal is None:
            raise ValueError("mode 'cartesian' needs a goal")
        if self.mode == "gripper" and self.gripper is None:
            raise ValueError("mode 'gripper' needs gripper")
        return self
