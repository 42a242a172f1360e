"""Next-best-view planning (Ch. 4): evaluated candidate views and the chosen one."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from schemas.arrays import Array, Dim
from schemas.base import Message, Stamped
from schemas.types import Finite, Pose, Poses, Rigid, Vec3, check_roi


def _column(dtype: str = "float64", description: str = "") -> Array:
    return Array(dtype, ("n",), description=description)


class ViewCandidates(Stamped):
    """Every view v evaluated in one planning step, column-wise: IG(v) (Eq. 4.6), c(v)
    (Eq. 4.9, inf when unreachable), u(v) (Eq. 4.13)."""

    step: int = Field(ge=0)
    strategy: str
    sampling: str
    center: Vec3 = Field(description="view-sphere centre")
    views: Annotated[np.ndarray, Array("float64", ("n", 4, 4)), Rigid()] = Field(
        description="T_world_camera of each view"
    )
    base_pose: Annotated[np.ndarray, Array("float64", ("n", 3)), Finite()] = Field(
        description="platform pose (x, y, yaw) of each view (Eq. 4.2, 4.3)"
    )
    information_gain: Annotated[
        np.ndarray, _column(description="predicted IG; 0 where c = ∞ is certain without a search")
    ]
    cost: Annotated[np.ndarray, _column(description="s, inf if unreachable")]
    utility: Annotated[np.ndarray, _column()]
    saliency: Annotated[np.ndarray, _column()]
    reachable: Annotated[np.ndarray, _column("bool")]


class NextBestView(Stamped):
    """v̂ = argmax u(v), as a platform pose plus joint targets; or the decision to stop."""

    step: int = Field(ge=0)
    strategy: str
    view: Pose = Field(description="T_world_camera of the chosen view")
    x: float
    y: float
    yaw: float
    joint_names: Annotated[list[str], Dim("k")]
    joint_positions: Annotated[np.ndarray, Array("float64", ("k",)), Finite()]
    target: Vec3 = Field(description="the point the view looks at (fixation for the gaze)")
    information_gain: float
    cost: float
    utility: float
    terminate: bool = False
    reason: Literal["", "quality", "max_views", "no_candidates"] = ""
    detail: str = Field("", description="why, in words (e.g. why no candidate was reachable)")
    workers: int = Field(1, ge=1, description="nbv instances that evaluated the candidates")


class GainRequest(Message):
    """A request on ``nbv/gain/<instance>``: the coarse information gain (every n-th ray, the
    planner's measure) of these views, on the worker's own copy of the current map: one share
    of a planning step's candidates (fan-out over the live nbv instances)."""

    views: Poses


class Gains(Message):
    """The reply: one gain per requested view, and who computed them."""

    gains: Annotated[np.ndarray, Array("float64", ("n",)), Finite()]
    worker: str


#: the largest step number and number of visited poses a plan request may carry
MAX_PLAN_STEP = 100_000
MAX_VISITED = 10_000
MAX_CENTRES = 100
#: m: a candidate view whose platform pose is this close to an excluded one is not planned
EXCLUDED_RADIUS = 0.25
#: m: the radius of the obstacle a path planner marks where the platform got stuck
BLOCKED_RADIUS = 0.1


class PlanRequest(Message):
    """A request on ``nbv/plan``: plan step ``step`` from the robot's current pose. ``initial``
        only aims the head at the view-sphere centre from where the robot stands (the first view);
        ``visited`` are the platform poses of the views taken so far (for the top-down sampling's
        largest arc); with ``execute`` the planner also sends the BaseGoal and the HeadCommand;
        ``excluded``: goals the platform could not reach, not planned again; ``blocked``: where it
    got stuck on the way (an obstacle for the paths that follow); ``centres`` and the
        roi, where given, replace the planner's settings (the explorer's scene: an episode's
        facts travel with its requests). An ``initial`` request begins an episode: λ_quality's
        reference, the first step's best gain, is taken anew."""

    step: int = Field(0, ge=0, le=MAX_PLAN_STEP)
    initial: bool = False
    execute: bool = True
    visited: Annotated[np.ndarray, Array("float64", (None, 3)), Finite()] = Field(
        default_factory=lambda: np.zeros((0, 3))
    )

    excluded: Annotated[np.ndarray, Array("float64", (None, 3)), Finite()] = Field(
        default_factory=lambda: np.zeros((0, 3)),
        description="platform poses (x, y, yaw) not to plan a view from: goals the platform "
        "did not reach (a candidate within EXCLUDED_RADIUS of one is unreachable)",
    )

    blocked: Annotated[np.ndarray, Array("float64", (None, 4)), Finite()] = Field(
        default_factory=lambda: np.zeros((0, 4)),
        description="where the platform got stuck on what the map does not hold (a glass "
        "pane, a wall no camera saw), as (x, y, dx, dy): its position and the unit direction "
        "it drove; the path planner marks an obstacle of BLOCKED_RADIUS just ahead of its "
        "footprint there",
    )

    centres: Annotated[np.ndarray, Array("float64", (None, 3)), Finite()] = Field(
        default_factory=lambda: np.zeros((0, 3)),
        description="view-sphere centres of this plan, the first one the initial view's "
        "target (empty: the planner's settings)",
    )
    roi_min: Vec3 | None = Field(
        None, description="the box whose unknown voxels IG counts (None: the planner's settings)"
    )
    roi_max: Vec3 | None = None

    @field_validator("centres")
    @classmethod
    def _few_centres(cls, v: np.ndarray) -> np.ndarray:
        if len(v) > MAX_CENTRES:
            raise ValueError(f"{len(v)} view-sphere centres: at most MAX_CENTRES={MAX_CENTRES}")
        return v

    @model_validator(mode="after")
    def _roi_whole(self) -> PlanRequest:
        check_roi(self.roi_min, self.roi_max)
        return self

    @field_validator("visited", "excluded")
    @classmethod
    def _few_visited(cls, v: np.ndarray) -> np.ndarray:
        if len(v) > MAX_VISITED:
            raise ValueError(f"{len(v)} visited poses: at most MAX_VISITED={MAX_VISITED}")
        return v
