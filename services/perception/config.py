"""Settings of the perception service (env AVS_PERCEPTION_<FIELD> or --flag)."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from services.common.config import ServiceSettings


class PerceptionSettings(ServiceSettings):
    """RGB-D frames → geometric primitives, spatial and support graph, affordances."""

    SERVICE: ClassVar[str] = "perception"

    camera: str = Field("head_rgbd", description="camera whose frames to perceive ('*': all)")
    depth_min: float = Field(0.35, ge=0, description="nearest depth used, m")
    depth_max: float = Field(3.0, gt=0, description="farthest depth used, m")
    stride: int = Field(2, ge=1, le=4, description="pixel stride of the organized cloud")
    smooth_per_m2: float = Field(
        0.0,
        ge=0,
        description="normals averaged over a window of half-width round(this · z²) grid steps "
        "where that is wider than 1 (structured-light depth comes in steps growing with z²: "
        "0.45 for a Kinect v1 at 2-3 m); 0: a 3-wide window everywhere",
    )
    self_mask: bool = Field(
        True,
        description="mask the robot's own body (its MJCF posed by the joints a frame carries)",
    )
    self_mask_margin: float = Field(0.02, ge=0, description="grown by this much, m")
    max_pixels: int = Field(1280 * 960, gt=0, description="larger frames are dropped")
    seed: int = Field(0, description="seed of RANSAC")
    queue: int = Field(
        2, ge=1, description="frames this worker owns and has not begun, at most (older: stale)"
    )
    max_rate: float = Field(
        0.0,
        ge=0,
        description="frames this worker perceives a second at most, the newest when "
        "its time comes (the others dropped as 'rate', counted); 0: every frame",
    )
    realtime: bool = Field(
        True,
        description="the worker at nice -5 where permitted: after the real-time loops, before "
        "rendering, tools and the map",
    )
