"""Settings of the explorer (env AVS_EXPLORER_<FIELD> or --flag)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, model_validator

from services.common.config import ServiceSettings


class ExplorerSettings(ServiceSettings):
    """The active-vision loop: next-best views taken one after the other (thesis 4.5)."""

    SERVICE: ClassVar[str] = "explorer"

    clock: Literal["wall", "lockstep"] = Field(
        "wall",
        description="wall: wait on the live streams (nothing steps); lockstep: step sim/control "
        "while the platform and head move, render each view",
    )
    autostart: bool = Field(
        False, description="start an episode once the services it needs are up (``needs``)"
    )
    needs: list[str] = Field(
        ["nbv", "perception", "scene_memory"],
        description="autostart: the services whose liveliness tokens the episode waits for "
        "(a frame not fused within capture_timeout_s ends an episode: a scene memory still "
        "starting would end it at its first view)",
    )
    views: int = Field(10, ge=1, le=1000, description="views an episode takes at most")
    roi_min: list[float] | None = Field(
        None, description="x,y,z: the scene's region of interest (whose unknown voxels count)"
    )
    roi_max: list[float] | None = None
    roi_from_sim: bool = Field(
        True,
        description="with no roi given (settings or start request), the one a simulated "
        "scene declares (sim/ground_truth: task metadata, not the truth of its objects)",
    )
    centres: list[float] | None = Field(
        None,
        description="view-sphere centres x,y,z[,x,y,z…], the first one the first view's target "
        "(default: the roi's centre)",
    )
    camera: str = Field("head_rgbd", description="the camera whose frames are the views")
    tick_s: float = Field(0.05, gt=0, le=1, description="wall clock: the loop's period, s")
    step_s: float = Field(0.1, gt=0, le=10, description="lockstep: sim time stepped a tick, s")
    head_still: float = Field(0.05, gt=0, description="rad/s: the head has arrived below this")
    base_still: float = Field(0.03, gt=0, description="m/s, rad/s: the platform likewise")
    settle_hold_s: float = Field(0.3, ge=0, description="still for this long: settled")
    settle_timeout_s: float = Field(8.0, gt=0, description="then the view is taken anyway")
    move_margin_s: float = Field(
        10.0, gt=0, description="a goal not reached in 2 × its estimated time + this: abandoned"
    )
    capture_timeout_s: float = Field(
        30.0, gt=0, description="a frame after settling fused and mapped within this, or stop"
    )
    plan_timeout_s: float = Field(300.0, gt=0, description="one plan query waits this long")
    hold: bool = Field(
        False,
        description="after each view but the last, wait (paused) for a resume on "
        "explore/control: an evaluator scores the view while the sim stands still (lockstep)",
    )
    gaze_priority: float = Field(
        1.0, description="priority of the view's target on gaze/target (manual targets win)"
    )

    @model_validator(mode="after")
    def _roi(self) -> ExplorerSettings:
        box = (self.roi_min, self.roi_max)
        if (box[0] is None) != (box[1] is None):
            raise ValueError("roi_min and roi_max come together")
        if box[0] is not None and (len(box[0]) != 3 or len(box[1]) != 3):
            raise ValueError("roi_min and roi_max are x,y,z")
        if self.centres is not None and (not self.centres or len(self.centres) % 3):
            raise ValueError("centres are x,y,z triples")
        return self
