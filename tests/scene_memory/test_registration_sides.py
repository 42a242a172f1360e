"""Registration from the other side of the table (issue 43): a frame from the far side, its
odometry 5 cm and 5° off, registers to within 1 cm and 0.5° against the map of the near side
(the local stage alone refuses it: the correction is past what it allows itself); a scene that
looks the same from many poses (a round table with a vase at its centre) is refused, not
guessed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from services.common.poses import pose_difference
from services.scene_memory.hypotheses import SearchConfig, search, turned
from services.scene_memory.memory import MemoryConfig, SceneMemory
from services.scene_memory.occupancy import OccupancyConfig
from services.scene_memory.registration import (
    RegistrationConfig,
    RegistrationMap,
    camera_points,
    register,
)
from services.sim import capture
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR6
from services.sim.world import World, look_target
from tests.scene_memory.test_registration_behind import look_at

#: the search's window set to the odometry error these tests inject (5 cm / 5°, and a margin):
#: by default it allows what the local stage does, 10 cm / 4°
WIDE = SearchConfig(max_correction_m=0.1, max_correction_deg=7.0)


@pytest.fixture(scope="module")
def sides():
    """tabletop_clutter from the robot 1.2 m from the table's centre, on the near side and on
    the far side, depth noise on: the two frames at their true poses."""
    world = World("tabletop_clutter", ARMAR6)
    renderer = CameraRenderer(world.model, 640, 480)
    centre = look_target(world)
    rng = np.random.default_rng(0)
    frames = []
    for seq, a in enumerate((math.pi, 0.0)):
        x, y = centre[0] + 1.2 * math.cos(a), centre[1] + 1.2 * math.sin(a)
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        world.look_at(centre)
        T, _ = capture.snapshot(world, renderer, "head_rgbd")
        frames.append(capture.frame(world, renderer, "head_rgbd", T, float(seq), seq, rng))
    renderer.close()
    return frames


def odometry_error(T: np.ndarray, k: int) -> np.ndarray:
    """``T`` 5 cm off in the ground plane (direction k of four) and turned 5° (alternating)
    about the vertical through the camera."""
    out = turned(T, 5.0 if k % 2 == 0 else -5.0)
    a = k * math.pi / 2 + math.pi / 4
    out[:2, 3] += 0.05 * np.array([math.cos(a), math.sin(a)])
    return out


def points(frame) -> np.ndarray:
    return camera_points(frame.depth, frame.intrinsics, 0.35, 3.0)


@pytest.mark.parametrize("k", range(4))
def test_a_frame_from_the_far_side_registers_to_1_cm(sides, k):
    near, far = sides
    T_near, T_far = np.asarray(near.T_world_camera), np.asarray(far.T_world_camera)
    c = RegistrationConfig()
    near_world = points(near) @ T_near[:3, :3].T + T_near[:3, 3]
    target = RegistrationMap.of(near_world, c, T_near[:3, 3])
    T_prior = odometry_error(T_far, k)
    assert pose_difference(T_far, T_prior) == pytest.approx((0.05, 5.0), abs=1e-6)
    local = register(points(far), T_prior, target, c)
    assert not local.accepted  # 5° is more than the local stage corrects
    result, found = search(points(far), T_prior, target, c, WIDE, map_points=near_world)
    assert result.accepted, (result.reason, [(h.fitness, h.reason) for h in found])
    assert result.outlined
    moved, turn = pose_difference(T_far, result.T_world_camera)
    assert moved <= 0.01 and turn <= 0.5, (moved, turn)
    assert np.allclose(result.correction @ T_prior, result.T_world_camera)


def test_the_memory_corrects_the_odometry_from_the_far_side(sides):
    """In the memory: the near frame defines the map, the far one arrives with its odometry
    5 cm / 5° off; the search corrects it, its pose refined by the outlines of the map's
    registered cloud (1 cm voxels): 10.3 mm and 0.40° off (2026-12-07; 6.2 mm and 0.27° by
    point-to-plane alone on this table, which shows the far side round cans and a ball; on
    generated tables the search with the outlines takes 39 of 120 errors within 1 cm and
    0.5°, ``benchmarks/registration_sides.py``). Without the search the prior stands."""
    near, far = sides
    T_far = np.asarray(far.T_world_camera)
    drifted = far.model_copy(update={"T_world_camera": odometry_error(T_far, 1)})
    out = {}
    for name, s in (("search", WIDE), ("local", None)):
        memory = SceneMemory(MemoryConfig(
            occupancy=OccupancyConfig(voxel=0.02), registration=RegistrationConfig(), search=s
        ))  # fmt: skip
        memory.integrate(near)
        memory.integrate(drifted)
        correction = np.eye(4) if memory.T_world_odom is None else memory.T_world_odom
        T = correction @ np.asarray(drifted.T_world_camera)
        out[name] = (pose_difference(T_far, T), memory.last_registration)
        out.setdefault("memory", memory)
    (moved, turn), last = out["search"]
    assert last["accepted"] and last["searched"], last
    assert moved <= 0.012 and turn <= 0.5, (moved, turn)
    # the sim reset: its clock starts again, earlier than the last search, and the odometry is
    # off again; the search is due at once (time went back), as registration is
    memory = out["memory"]
    T_odom = np.linalg.inv(memory.T_world_odom) @ odometry_error(T_far, 2)
    memory.integrate(far.model_copy(update={"T_world_camera": T_odom, "stamp": 0.5}))
    last = memory.last_registration
    assert last["accepted"] and last["searched"], last
    moved, turn = pose_difference(T_far, memory.T_world_odom @ T_odom)
    assert moved <= 0.012 and turn <= 0.5, (moved, turn)
    (moved, turn), last = out["local"]
    assert not last["accepted"] and (moved, turn) == pytest.approx((0.05, 5.0), abs=1e-6)


def surface(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    return np.vstack([p for p, _ in parts]), np.vstack([n for _, n in parts])


def disc(radius: float, z: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    g = np.arange(-radius, radius, step)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    inside = u**2 + v**2 <= radius**2
    p = np.column_stack([u[inside], v[inside], np.full(inside.sum(), z)])
    return p, np.tile([0.0, 0.0, 1.0], (len(p), 1))


def band(radius: float, z0: float, z1: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """An upright cylinder's side about the world's z axis, outward normals."""
    a, h = (x.ravel() for x in np.meshgrid(np.arange(0, 2 * math.pi, step / radius),
                                           np.arange(z0, z1, step)))  # fmt: skip
    n = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    return np.column_stack([radius * n[:, :2], h]), n


def seen(P: np.ndarray, N: np.ndarray, T: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The points a camera at T sees (camera frame): in its field of view (60° × 45°), facing
    it, the floor under the table top hidden; 2 mm of noise."""
    cam = (P - T[:3, 3]) @ T[:3, :3]
    z = cam[:, 2]
    fov = (z > 0.35) & (np.abs(cam[:, 0]) < 0.55 * z) & (np.abs(cam[:, 1]) < 0.42 * z)
    facing = (N * (T[:3, 3] - P)).sum(axis=1) > 0
    r = np.hypot(P[:, 0], P[:, 1])
    under = (P[:, 2] < 0.7) & (r < 0.5) & (r > 0.06)
    keep = cam[fov & facing & ~under]
    return keep + rng.normal(0.0, 0.002, keep.shape)


def test_a_scene_that_fits_many_poses_is_refused():
    """A round table on a pedestal with a vase at its centre: turned about its axis it is the
    same, so the far side's frame fits every yaw about it. The local stage and the search
    both say no and keep the prior. Of the checks, the conditioning (a ratio) passes it:
    the share of the frame on upright surfaces that holds the weakest direction does not (0
    here: the vase's and the rim's normals all point at the axis)."""
    rng = np.random.default_rng(0)
    P, N = surface([
        disc(0.5, 0.75, 0.005), band(0.5, 0.72, 0.75, 0.005), band(0.05, 0.0, 0.72, 0.005),
        band(0.05, 0.75, 0.95, 0.005), disc(0.05, 0.95, 0.005), disc(1.6, 0.0, 0.01),
    ])  # fmt: skip
    centre = np.array([0.0, 0.0, 0.8])
    T_near = look_at(np.array([-1.3, 0.2, 1.4]), centre)
    T_far = look_at(np.array([1.3, -0.2, 1.4]), centre)
    c = RegistrationConfig()
    near = seen(P, N, T_near, rng)
    target = RegistrationMap.of(near @ T_near[:3, :3].T + T_near[:3, 3], c, T_near[:3, 3])
    far = seen(P, N, T_far, rng)
    for k in range(4):
        T_prior = odometry_error(T_far, k)
        local = register(far, T_prior, target, c)
        assert not local.accepted, local
        assert local.strength < c.min_strength and local.conditioning > c.min_conditioning
        result, found = search(far, T_prior, target, c, WIDE)
        assert not result.accepted and not found, result
        assert np.array_equal(result.T_world_camera, T_prior)
