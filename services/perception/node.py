"""The perception node: the newest RGB-D frame in, one SceneObservation out.

Frames arrive on a latest-only input, so a slow step never builds a queue of stale frames.
A frame without depth, or larger than ``max_pixels``, is dropped and counted; an empty or
all-invalid frame gives an observation with no primitives.
"""

from __future__ import annotations

import logging

from schemas import RgbdFrame
from services.common.node import Node
from services.perception.config import PerceptionSettings
from services.perception.pipeline import Perception, PerceptionConfig, observation

log = logging.getLogger("avs.perception")


class PerceptionNode:
    def __init__(self, node: Node, settings: PerceptionSettings) -> None:
        self.node, self.settings = node, settings
        self.perception = Perception(
            PerceptionConfig(
                depth_min=settings.depth_min,
                depth_max=settings.depth_max,
                stride=settings.stride,
                seed=settings.seed,
            )
        )
        self.perception.warm_up()
        self.out = node.publisher(node.keys.observation())
        self.seq = 0
        self.key = node.keys.rgbd(settings.camera)
        node.subscribe(self.key, RgbdFrame, self.on_frame, latest_only=True)

    def on_frame(self, frame: RgbdFrame) -> None:
        if frame.depth is None:
            self.node.drop("no_depth", self.key, f"frame of {frame.camera} has no depth")
            return
        pixels = frame.intrinsics.width * frame.intrinsics.height
        if pixels > self.settings.max_pixels:
            self.node.drop(
                "oversized",
                self.key,
                f"{frame.intrinsics.width}×{frame.intrinsics.height} frame is larger "
                f"than {self.settings.max_pixels} pixels",
            )
            return
        result = self.perception.perceive(
            frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera
        )
        c = self.perception.config
        self.out.put(
            observation(result, frame, self.seq, self.node.instance, c.depth_max, c.stride)
        )
        self.seq += 1
        self.node.metrics.gauge("primitives", len(result.primitives))
        self.node.metrics.gauge("total_ms", result.timings_ms["total"])
