"""Gaze (Ch. 5): fixation targets and the sensory ego-sphere."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from pydantic import Field

from schemas.arrays import Array
from schemas.base import Stamped
from schemas.types import Vec3


class GazeTarget(Stamped):
    """A 3D fixation point x_des in the world. Higher ``priority`` wins while fresh."""

    point: Vec3
    source: str = Field(description="nbv, manual, saliency, object …")
    priority: float = 0.0
    camera: str = Field("", description="camera whose optical axis should hold it; '' = main")
    hold_s: float = Field(5.0, gt=0, description="how long the target stays fresh")


class EgoSphereSnapshot(Stamped):
    """The sensory ego-sphere (5.1), downsampled for viewers: unit directions in the head frame
    with their aggregated saliency s_j (Eq. 5.1)."""

    frame: str = "head_base"
    directions: Annotated[np.ndarray, Array("float32", ("n", 3))]
    saliency: Annotated[np.ndarray, Array("float32", ("n",))]
    reachable: Annotated[np.ndarray, Array("bool", ("n",))]
    winner: int = Field(-1, ge=-1, description="index of the winning direction, -1 if none")
    sources: list[str] = Field(default_factory=list, description="active saliency sources")
