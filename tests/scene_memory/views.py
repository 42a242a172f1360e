"""Six views of tabletop_clutter rendered once for the scene memory's tests, and the memory an
uninterrupted, in-process run of them builds (what every restart must get back to)."""

from __future__ import annotations

import math

import numpy as np

from schemas import RgbdFrame, SceneModel, SceneObservation, decode, encode
from services.perception.pipeline import Perception, observation
from services.scene_memory.fusion import FusionConfig
from services.scene_memory.memory import MemoryConfig, SceneMemory
from services.scene_memory.occupancy import OccupancyConfig
from services.sim import capture
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR6
from services.sim.world import World, look_target

BOUNDS_MIN, BOUNDS_MAX = [-0.5, -1.5, -0.05], [2.5, 1.5, 1.6]
VOXEL = 0.02
Update = tuple[str, RgbdFrame | SceneObservation]


def render_updates() -> list[Update]:
    """Six views of tabletop_clutter on an arc: frame, then its observation, for each."""
    world = World("tabletop_clutter", ARMAR6)
    renderer = CameraRenderer(world.model, 320, 240)
    perception = Perception()
    centre = look_target(world)
    sx, sy, _ = world.info.robot_start
    r, a0 = math.hypot(sx - centre[0], sy - centre[1]), math.atan2(sy - centre[1], sx - centre[0])
    out: list[Update] = []
    rng = np.random.default_rng(0)
    for i, a in enumerate(a0 + np.radians([-30, -18, -6, 6, 18, 30])):
        x, y = centre[0] + r * math.cos(a), centre[1] + r * math.sin(a)
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        world.look_at(centre)
        T, stamp = capture.snapshot(world, renderer, "head_rgbd")
        frame = capture.frame(world, renderer, "head_rgbd", T, stamp, i, rng)
        result = perception.perceive(frame.depth, frame.rgb, frame.intrinsics, T)
        out += [("frame", frame), ("observation", observation(result, frame, i, "t", 3.0, 1))]
    renderer.close()
    return out


def reference(updates: list[Update]) -> SceneMemory:
    memory = SceneMemory(
        MemoryConfig(
            bounds_min=tuple(BOUNDS_MIN),
            bounds_max=tuple(BOUNDS_MAX),
            fusion=FusionConfig(mode="sg"),
            occupancy=OccupancyConfig(voxel=VOXEL),
        )
    )
    for kind, message in updates:
        # through the wire format, as the service sees it
        if kind == "frame":
            memory.integrate(decode(encode(message), RgbdFrame))
        else:
            memory.fuse(decode(encode(message), SceneObservation))
    return memory


def summary(scene: SceneModel) -> tuple:
    """What must survive a restart: every primitive's kind, model and box, the support graph
    with occ(e), the version."""
    prims = tuple(
        (p.id, p.model.kind, tuple(np.round(p.obb.center, 6)), tuple(np.round(p.obb.extent, 6)))
        for p in scene.primitives
    )
    edges = tuple((e.supporter, e.supported, e.occ) for e in scene.support_edges)
    return prims, edges, scene.model_version, scene.n_views
