"""Perceiving an unorganized world cloud (``pointset.py``, ``Perception.perceive_points``): what
``pc`` fusion re-extracts the scene from (thesis 3.3.1). Two views of tabletop_occluded merged
in the scene memory find the support that the start view cannot see, and the memory in ``pc``
mode is what the merged cloud shows, in ``pc+sg`` it counts it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from experiments import evaluation
from schemas import CloudFrame, SceneObservation, decode, encode
from services.perception.pipeline import Perception, cloud_observation, observation
from services.perception.pointset import point_set, segment_points
from services.scene_memory.fusion import FusionConfig
from services.scene_memory.memory import MemoryConfig, SceneMemory, registered_cloud
from services.scene_memory.occupancy import OccupancyConfig
from services.sim import capture, ground_truth
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR6
from services.sim.world import World, look_target

HIDDEN = ("box_base", "cylinder_top")  # the stack's contact, behind box_front from the start


def _support(gt, obs: SceneObservation, seen) -> evaluation.SupportScores:
    scores = evaluation.score_primitives(
        evaluation.merge_points(seen), obs.primitives, scope=evaluation.bodies_in_roi(gt)
    )
    edges = [(e.supporter, e.supported) for e in obs.support_edges]
    return evaluation.score_support(gt, edges, scores.bodies)


@pytest.fixture(scope="module")
def two_views():
    """tabletop_occluded from the start side and from 70° round the table (no sensor noise):
    the frames, each view's own observation, the memory of both (roi set) and the truth."""
    world = World("tabletop_occluded", ARMAR6)
    renderer = CameraRenderer(world.model, 640, 480)
    centre = look_target(world)
    roi = world.info.roi
    edges, closure = ground_truth.support_graph(world.model, world.data, world.info)
    perception = Perception()
    memory = SceneMemory(
        MemoryConfig(
            bounds_min=(-1.0, -2.5, -0.05), bounds_max=(3.0, 2.5, 2.0),
            fusion=FusionConfig(mode="pc"), occupancy=OccupancyConfig(voxel=0.02),
            roi=(tuple(roi[0]), tuple(roi[1])),
        )
    )  # fmt: skip
    frames, views, seen, gt = [], [], [], None
    for i, degrees in enumerate((0.0, 70.0)):
        a = math.pi + math.radians(degrees)
        x, y = centre[0] + 1.3 * math.cos(a), centre[1] + 1.3 * math.sin(a)
        world.place(base=(x, y, math.atan2(centre[1] - y, centre[0] - x)))
        world.look_at(centre)
        T, stamp = capture.snapshot(world, renderer, "head_rgbd")
        frame = capture.frame(world, renderer, "head_rgbd", T, stamp, i, None)
        labels, seg = capture.segmentation(world, renderer, "head_rgbd")
        gt = capture.ground_truth_message(world, edges, closure, "head_rgbd", labels, seg)
        seen.append(evaluation.labelled_points(gt, frame.depth, frame.intrinsics, T))
        memory.integrate(frame)
        result = perception.perceive(frame.depth, frame.rgb, frame.intrinsics, T)
        frames.append(frame)
        views.append(observation(result, frame, i, "t", 3.0, perception.config.stride))
    renderer.close()
    return frames, views, memory, gt, seen


def test_the_merged_cloud_of_two_views_finds_the_support_the_start_view_misses(two_views):
    frames, views, memory, gt, seen = two_views
    start = _support(gt, views[0], seen)
    assert HIDDEN not in start.edges and start.f1 < 0.7, start  # 0.67: the stack's contact
    cloud = decode(encode(registered_cloud(memory, frames[1])), CloudFrame)  # over the wire
    lo, hi = np.asarray(memory.config.roi[0]) - 0.03, np.asarray(memory.config.roi[1]) + 0.03
    assert np.all((cloud.points >= lo) & (cloud.points <= hi))  # the roi's, 3 cm margin
    assert 10_000 < len(cloud.points) < 20_000  # 13,740: one point per 1 cm voxel
    # each point was seen from one of the two cameras
    cams = np.array([f.T_world_camera[:3, 3] for f in frames])
    assert np.min(np.linalg.norm(cloud.viewpoints[:, None] - cams[None], axis=2), 1).max() < 1e-5
    result = Perception().perceive_points(
        cloud.points, cloud.viewpoints, cloud.colours, cloud.T_world_camera[:3, 3]
    )
    assert result.timings_ms["total"] < 1000  # 70 ms here
    merged = _support(gt, cloud_observation(result, cloud, 0, "t"), seen)
    assert merged.f1 == 1.0, merged
    assert set(merged.edges) == {("table", "box_front"), ("table", "box_base"),
                                 ("table", "cup"), HIDDEN}  # fmt: skip


def test_pc_takes_the_merged_extraction_as_the_model_and_pc_plus_sg_counts_it(two_views):
    frames, _, memory, gt, seen = two_views
    cloud = registered_cloud(memory, frames[1])
    result = Perception().perceive_points(
        cloud.points, cloud.viewpoints, cloud.colours, cloud.T_world_camera[:3, 3]
    )
    obs = cloud_observation(result, cloud, 0, "t")
    occ = {}
    for mode in ("pc", "pc+sg"):
        m = SceneMemory(
            MemoryConfig(
                fusion=FusionConfig(mode=mode),
                roi=memory.config.roi,
                occupancy=OccupancyConfig(voxel=0.05),
            )
        )
        m.fuse(obs)
        update = m.fuse(obs)  # the same cloud again
        scene = m.scene()
        assert scene.n_views == 2
        occ[mode] = sorted(e.occ for e in scene.support_edges)
        # the table (a box), box_front, box_base, cylinder_top and the cup
        assert len(obs.primitives) == len(scene.primitives) == 5
        if mode == "pc":  # replaced: the model is this extraction, nothing of the last
            assert update.removed == update.added == 5
        else:  # fused with itself: every primitive matched, none added
            assert update.added == 0
        f1 = _support(gt, scene, seen).f1
        assert f1 == 1.0, (mode, f1)
    assert occ == {"pc": [1, 1, 1, 1], "pc+sg": [2, 2, 2, 2]}


def test_point_set_normals_face_their_viewpoints_and_creases_part_a_box_from_its_table():
    """A 40 cm table top at z = 0 with a 10 cm cube on it, sampled at 1 cm, each point seen
    from a camera 1 m up and out from its face (cameras all round): normals up on the top,
    out on the cube's faces; the concave crease around the cube's foot parts the two, and
    the crease's points join one side or the other."""
    g = np.arange(-0.2, 0.2001, 0.01)
    top = np.array([(x, y, 0.0) for x in g for y in g if not (abs(x) < 0.05 and abs(y) < 0.05)])
    c = np.arange(-0.05, 0.0501, 0.01)
    h = np.arange(0.0, 0.1001, 0.01)
    cube = np.unique(np.concatenate([
        [(x, y, 0.1) for x in c for y in c],
        [(x, s, z) for x in c for s in (-0.05, 0.05) for z in h[1:]],
        [(s, y, z) for y in c for s in (-0.05, 0.05) for z in h[1:]],
    ]).round(4), axis=0)  # fmt: skip
    points = np.concatenate([top, cube])
    out = np.zeros_like(points)  # the horizontal outward direction of a cube's side
    side = (
        (np.abs(points[:, :2]).max(axis=1) < 0.0501) & (points[:, 2] > 1e-9) & (points[:, 2] < 0.1)
    )
    k = np.argmax(np.abs(points[side, :2]), axis=1)
    out[np.flatnonzero(side), k] = np.sign(points[side, k])
    ps = point_set(points, points + out + [0.0, 0.0, 1.0])
    n_top = ps.normals[: len(top)]
    inner = np.all(np.abs(top) < 0.15, axis=1) & np.any(np.abs(top) > 0.08, axis=1)
    assert np.all(n_top[inner, 2] > 0.99)  # up: towards the camera
    front = np.flatnonzero(np.isclose(points[:, 1], -0.05) & (points[:, 2] > 0.03)
                           & (points[:, 2] < 0.08) & (np.abs(points[:, 0]) < 0.03))  # fmt: skip
    assert np.all(ps.normals[front, 1] < -0.99)  # the cube's front face: out, to its camera
    labels, n = segment_points(ps, min_size=15)
    assert n == 2 and np.all(labels >= 0)  # every point in one of the two
    # away from the crease (2 cm: the normals' neighbourhood) each is one region
    table = labels[: len(top)][np.any(np.abs(top[:, :2]) > 0.075, axis=1)]
    box = labels[len(top) :][cube[:, 2] > 0.025]
    assert set(table) == {0} and set(box) == {1}  # the table top is the larger
    # the graph's helpers: components among given points, and one step of growth
    _, k = ps.labels(np.arange(len(points)))
    assert k == 1  # touching: one component of the graph itself
    ring = np.flatnonzero(np.abs(points[:, 2]) < 1e-9)
    grown = ps.near(np.arange(len(points)), np.isin(np.arange(len(points)), ring))
    assert grown.sum() > len(ring)  # and the cube's lowest side points (1 cm above)
    assert np.all(points[grown, 2] <= 0.02 + 1e-9)
