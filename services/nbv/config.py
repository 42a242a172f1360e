"""Settings of the next-best-view planner (env AVS_NBV_<FIELD> or --flag)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field, field_validator

from services.common.config import ServiceSettings


class NbvSettings(ServiceSettings):
    """View sphere, sampling, information gain, path cost, utility (thesis Ch. 4)."""

    SERVICE: ClassVar[str] = "nbv"

    camera: str = Field("head_rgbd", description="the camera whose views are planned")
    centre: list[float] | None = Field(
        None,
        description="view-sphere centres x,y,z[,x,y,z…] (a scene's points of interest; "
        "default: the map's middle at 0.9 m)",
    )
    first_target: list[float] | None = Field(
        None, description="x,y,z the first view looks at (default: the first centre)"
    )
    radius: float = Field(1.5, gt=0, description="view-sphere radius r, m (4.1)")
    sampling: Literal["equidistant", "random", "topdown"] = Field(
        "equidistant", description="view sampling (4.2)"
    )
    strategy: Literal["utility", "occupancy", "random", "saliency"] = Field(
        "utility", description="view evaluation (4.3, 4.5)"
    )
    lam: float = Field(0.5, ge=0, description="λ of u = IG̅ − λ·c̅ (Eq. 4.13)")
    lambda_s: float = Field(0.75, ge=0, le=1, description="λ_s of the edge saliency (Eq. 4.5)")
    lambda_quality: float = Field(
        0.05,
        ge=0,
        description="stop when the best predicted gain falls below this share of the first one",
    )
    max_views: int = Field(10, ge=1, description="stop after this many views")
    k: int = Field(72, ge=4, description="equidistant grid step 2π/k")
    samples: int = Field(200, ge=1, description="random sampling: views per step")
    every: int = Field(30, ge=1, description="hierarchical IG: every n-th ray for all views")
    best_k: int = Field(3, ge=0, description="hierarchical IG: every ray for the best k")
    ig_measure: Literal["rays", "volume"] = Field(
        "volume",
        description="IG: rays (Eq. 4.6, a voxel counted once per ray through it) or volume "
        "(each count weighted by the share of the voxel the ray's pixel covers)",
    )
    max_range: float = Field(3.0, gt=0, description="sensor range of the predicted rays, m")
    map_min: list[float] | None = Field(
        None, description="box of the occupancy map fetched (default: all)"
    )
    map_max: list[float] | None = None
    workspace_min: list[float] | None = Field(None, description="x,y: the platform stays above")
    workspace_max: list[float] | None = Field(None, description="x,y: … and below")
    roi_min: list[float] | None = Field(None, description="box whose unknown voxels IG counts")
    roi_max: list[float] | None = None
    seed: int = Field(0, description="random sampling and strategy")

    @field_validator("centre")
    @classmethod
    def _triples(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and (not v or len(v) % 3):
            raise ValueError("centre takes x,y,z triples")
        return v
