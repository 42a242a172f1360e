"""The exploration loop as a service (thesis Algorithm 5 in a loop, 4.5): its state and how
to command it (``explore/status``, ``explore/control``)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, model_validator

from schemas.base import Message, Stamped
from schemas.types import Vec3, check_roi

ExplorePhase = Literal["idle", "plan", "move", "settle", "capture", "paused", "done"]
ExploreOp = Literal["status", "start", "pause", "resume", "stop"]


class ExploreControl(Message):
    """A request on ``explore/control``. ``start`` (from idle or done) begins an episode in
    ``roi_min``/``roi_max`` (the scene's region of interest; omitted: the explorer's settings),
    at most ``views`` views (0: the settings'); ``pause`` holds it where it is (the platform
    stopped), ``resume`` goes on, ``stop`` ends it (the platform brought to rest at once)."""

    op: ExploreOp = "status"
    roi_min: Vec3 | None = None
    roi_max: Vec3 | None = None
    views: int = Field(0, ge=0, le=1000)

    @model_validator(mode="after")
    def _roi_whole(self) -> ExploreControl:
        check_roi(self.roi_min, self.roi_max)
        return self


class ExploreStatus(Stamped):
    """The explorer's state, on ``explore/status`` at every change and as the reply to
    ``explore/control``. ``view`` counts the views taken; ``target`` is the point the current
    view looks at, ``goal`` its platform pose (x, y, yaw); the gains are the planner's
    prediction for the current view and what the last view realised (unknown roi voxels it
    made known); ``reason`` says why the episode stopped (``done``) or what it waits for."""

    episode: int = Field(0, ge=0, description="episodes started by this explorer")
    phase: ExplorePhase
    clock: Literal["lockstep", "wall"] = "wall"
    view: int = Field(0, ge=0)
    views: int = Field(0, ge=0, description="the episode's view limit")
    target: Vec3 | None = None
    goal: list[float] = Field(default_factory=list)
    predicted_gain: float = 0.0
    realised_gain: float = 0.0
    unknown: int = Field(-1, ge=-1, description="unknown roi voxels after the last view (-1: none)")
    abandoned: int = Field(0, ge=0, description="goals the platform did not reach in time")
    cost: float = Field(0.0, ge=0, description="the current view's path cost c(v), s (Eq. 4.9)")
    planning_s: float = Field(0.0, ge=0, description="how long the current view's plan took")
    frame_seq: int | None = Field(None, description="the frame of the last view taken")
    reason: str = ""
    detail: str = ""
    ok: bool = True
    error: str = ""
