"""The occupancy map (OctoMap semantics, 4.3.1): counts and slices of voxel states."""

from __future__ import annotations

from typing import Annotated, ClassVar

import numpy as np
from pydantic import Field, model_validator

from schemas.arrays import Array
from schemas.base import Message, Stamped
from schemas.types import Vec3


class BoxQuery(Message):
    """Query payload: an axis-aligned box in the world (min and max corners, m)."""

    box_min: Vec3
    box_max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> BoxQuery:
        if np.any(self.box_max < self.box_min):
            raise ValueError("box_max must be >= box_min on every axis")
        return self


class OccupancyStats(Stamped):
    """Voxel counts by state inside a box (the scene's roi by default)."""

    voxel_size: float = Field(gt=0)
    box_min: Vec3
    box_max: Vec3
    unknown: int = Field(ge=0)
    free: int = Field(ge=0)
    occupied: int = Field(ge=0)
    map_version: int = Field(ge=0)
    frames_integrated: int = Field(0, ge=0)
    frames_skipped: int = Field(
        0, ge=0, description="depth frames not integrated: the camera had not moved (keyframes)"
    )
    frame_seq: int | None = Field(
        None,
        description="seq of the newest depth frame the map took: integrated, or skipped as not "
        "a keyframe (None: none since this scene memory started)",
    )
    realised_volume: int = Field(
        0, description="unknown voxels of the scene's roi the last integrated frame made known"
    )
    realised_rays: float = Field(
        0.0,
        ge=0,
        description="Eq. 4.6 on the last frame's own rays: unknown roi voxels they crossed up "
        "to their returns (every 30th pixel, × 30), on the map before it",
    )


class OccupancySlice(Stamped):
    """Voxel states in a box: ``states[i, j, k]`` is the voxel whose min corner is
    ``origin + voxel_size·(i, j, k)``; 0 unknown, 1 free, 2 occupied."""

    UNKNOWN: ClassVar[int] = 0
    FREE: ClassVar[int] = 1
    OCCUPIED: ClassVar[int] = 2

    voxel_size: float = Field(gt=0)
    origin: Vec3
    states: Annotated[np.ndarray, Array("uint8", (None, None, None))]
    map_version: int = Field(ge=0)
    page: int = Field(0, ge=0, description="this reply's slab along x, from 0")
    pages: int = Field(1, ge=1, description="replies the slice came in (slabs along x)")

    @classmethod
    def join(cls, replies: list[OccupancySlice]) -> OccupancySlice:
        """One slice from the pages of a paged reply (slabs along x), checked complete: the
        first complete set of one map version when several answered."""
        groups: dict[tuple[int, int], dict[int, OccupancySlice]] = {}
        for r in replies:
            groups.setdefault((r.seq, r.map_version), {})[r.page] = r
        for pages in groups.values():
            first = next(iter(pages.values()))
            if len(pages) == first.pages and set(pages) == set(range(first.pages)):
                ordered = [pages[i] for i in range(first.pages)]
                return ordered[0].model_copy(
                    update={
                        "states": np.concatenate([p.states for p in ordered], axis=0),
                        "page": 0,
                        "pages": 1,
                    }
                )
        raise ValueError(f"no complete occupancy slice among {len(replies)} replies")
