"""What every consumer of depth frames checks before work starts: the frame's size against its
``max_pixels`` (a bigger one is dropped and counted), and its depth values (NaN, inf and
negative depths mean no return: set to 0 and counted as ``depth_invalid_pixels``)."""

from __future__ import annotations

import numpy as np

from schemas import RgbdFrame
from services.common.node import Node


def usable_depth_frame(node: Node, key: str, frame: RgbdFrame, max_pixels: int) -> RgbdFrame | None:
    """The frame with its invalid depths masked, or None (dropped and counted)."""
    if frame.depth is None:
        node.drop("no_depth", key, f"frame of {frame.camera} has no depth")
        return None
    pixels = frame.intrinsics.width * frame.intrinsics.height
    if pixels > max_pixels:
        node.drop("oversized", key, f"{frame.intrinsics.width}×{frame.intrinsics.height} frame "
                  f"is larger than max_pixels={max_pixels}")  # fmt: skip
        return None
    bad = ~(np.isfinite(frame.depth) & (frame.depth >= 0))
    n = int(np.count_nonzero(bad))
    if n == 0:
        return frame
    if node.metrics.add("depth_invalid_pixels", n):
        node.log.warning("NaN, inf or negative depths are taken as no return (counted as "
                         "depth_invalid_pixels)", extra={"key": key, "pixels": n})  # fmt: skip
    return frame.model_copy(update={"depth": np.where(bad, np.float32(0), frame.depth)})
