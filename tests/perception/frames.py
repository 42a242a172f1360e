"""A rendered RGB-D frame of tabletop_clutter from the robot's start, for the process tests."""

from __future__ import annotations

import numpy as np

from schemas import RgbdFrame
from services.sim import capture
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR6
from services.sim.world import World


def clutter_frame(width: int = 640, height: int = 480, seq: int = 0) -> RgbdFrame:
    world = World("tabletop_clutter", ARMAR6)
    renderer = CameraRenderer(world.model, width, height)
    T, stamp = capture.snapshot(world, renderer, "head_rgbd")
    frame = capture.frame(world, renderer, "head_rgbd", T, stamp, seq, np.random.default_rng(0))
    renderer.close()
    return frame
