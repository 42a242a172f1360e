"""Fusion on real-depth terms: planes seen far agree within the sensor's depth noise, a plane
that bridges two memory pieces joins them, and a primitive that later views see through
decays (thesis 3.3's spatio-temporal memory: a moved object leaves no phantom)."""

from __future__ import annotations

import numpy as np

from schemas import Obb, PlaneModel, Primitive
from services.scene_memory.evidence import ViewDepth, depth_sigma
from services.scene_memory.fusion import Fusion, FusionConfig
from tests.scene_memory.builders import box, camera_above, observation, plane

FLOOR = dict(x=(-0.3, 2.1), y=(-1.0, 1.0), z=0.0)


def wall(pid: int, y: tuple[float, float], x: float, z: tuple[float, float]) -> Primitive:
    """A vertical rectangle facing −x at x, over [y0, y1] × [z0, z1]."""
    rng = np.random.default_rng(pid)
    n = 1500
    pts = np.column_stack(
        [x + rng.normal(0, 0.002, n), rng.uniform(*y, n), rng.uniform(*z, n)]
    ).astype(np.float32)
    return Primitive(
        id=pid,
        model=PlaneModel(normal=np.array([-1.0, 0, 0]), d=x),
        obb=Obb(
            center=np.array([x, sum(y) / 2, sum(z) / 2]),
            rotation=np.eye(3),
            extent=np.array([0.004, y[1] - y[0], z[1] - z[0]]),
        ),
        inlier_count=n,
        inliers=pts,
    )


def facing_wall(distance: float, x_wall: float = 3.0) -> np.ndarray:
    """A camera at height 1 m looking along +x at a wall ``distance`` ahead."""
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # optical z → world x
    T[:3, 3] = [x_wall - distance, 0.0, 1.0]
    return T


def test_a_wall_seen_from_2_5_m_twice_18_mm_apart_stays_one_plane():
    # Kinect v1 at 2.5 m: σ 9.6 mm and depth in 18 mm steps; the two views' planes differ
    # by one step. With the simulator's tolerance (1 cm at any distance) they stayed two.
    T = facing_wall(2.5)
    views = [wall(1, (-0.8, 0.8), 3.0, (0.3, 1.7)), wall(1, (-0.6, 1.0), 3.018, (0.3, 1.7))]
    for strict, expected in ((0.0, 2), (FusionConfig.plane_offset_sigmas, 1)):
        fusion = Fusion(FusionConfig(plane_offset_sigmas=strict))
        for k, w in enumerate(views):
            fusion.update(observation(k, [w], T=T))
        assert len(fusion.prims) == expected
    # near the camera the tolerance is the simulator's: 1.8 cm apart at 1 m are two planes
    near = facing_wall(1.0)
    fusion = Fusion()
    for k, w in enumerate(views):
        fusion.update(observation(k, [w], T=near))
    assert len(fusion.prims) == 2
    assert 2 * depth_sigma(2.5) > 0.018 > 2 * depth_sigma(1.0)


def test_a_table_seen_in_two_halves_then_whole_becomes_one_plane():
    fusion = Fusion()
    # two ends 0.6 m apart: each a plane of its own (the gap is more than plane_gap)
    fusion.update(observation(0, [plane(0, **FLOOR), plane(1, (0.0, 0.35), (-0.4, 0.4), 0.72)]))
    # the second view's floor stops short of the first end: seeing the floor where it lies
    # would be seeing through it, and a plane one view saw goes once one view sees through it
    floor = dict(FLOOR, x=(0.5, 2.1))
    fusion.update(observation(1, [plane(0, **floor), plane(1, (0.95, 1.3), (-0.4, 0.4), 0.72)]))
    tops = [m for m in fusion.prims.values() if abs(m.primitive.obb.center[2] - 0.72) < 0.02]
    assert len(tops) == 2
    update = fusion.update(
        observation(2, [plane(0, **FLOOR), plane(1, (0.0, 1.3), (-0.4, 0.4), 0.72)])
    )
    tops = [m for m in fusion.prims.values() if abs(m.primitive.obb.center[2] - 0.72) < 0.02]
    assert len(tops) == 1 and update.removed == 1
    assert abs(tops[0].primitive.obb.extent[0] - 1.3) < 0.03
    assert tops[0].views == 3  # each view saw a part of it


def test_what_later_views_see_through_decays_and_what_they_cannot_see_stays():
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    arm = box(1, (0.9, 0.0, 1.2), (0.1, 0.1, 0.4))  # an arm above the table, then gone
    hidden = box(2, (0.6, 0.0, 0.5), (0.1, 0.1, 0.1))  # under the table: no view reaches it
    fusion = Fusion()
    fusion.update(observation(0, [table, arm, hidden]))
    ids = {m.primitive.obb.center[2].round(1): m.id for m in fusion.prims.values()}
    fusion.update(observation(1, [table, arm]))  # two views saw the arm
    first = fusion.update(observation(2, [table]))  # sees the table where the arm was
    assert first.decayed == 0 and len(fusion.prims) == 3  # once is not yet gone
    assert fusion.prims[ids[1.2]].seen_through == 1 and fusion.prims[ids[0.5]].seen_through == 0
    second = fusion.update(observation(3, [table]))
    assert second.decayed == 1 and ids[1.2] not in fusion.prims
    assert ids[0.5] in fusion.prims and ids[0.7] in fusion.prims
    # as much evidence against as there was for: an arm one view saw goes at the first view
    # that sees through it
    fusion = Fusion()
    fusion.update(observation(0, [table, arm]))
    assert fusion.update(observation(1, [table])).decayed == 1 and len(fusion.prims) == 1
    # a match resets the count: seen through, seen again, seen through is not two in a row
    fusion = Fusion()
    for k, prims in enumerate([[table, arm], [table, arm], [table], [table, arm], [table]]):
        fusion.update(observation(k, prims))
    assert len(fusion.prims) == 2
    # decay off: the phantom stays
    fusion = Fusion(FusionConfig(decay_views=0))
    for k, prims in enumerate([[table, arm], [table], [table]]):
        fusion.update(observation(k, prims))
    assert len(fusion.prims) == 2


def test_the_view_depth_holds_the_nearest_surface_of_each_cell():
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    # 32-px cells: the builder's 1500 random points leave one 16-px cell in ten empty, and
    # which one depends on the tests run before (the builders share one generator)
    depth = ViewDepth(observation(0, [table]), 32)
    # the camera 2.6 m above: the table 1.88 m below it in every cell it covers
    held = np.isfinite(depth.near)
    assert held.sum() > 50 and np.allclose(depth.near[held], 1.88, atol=0.01)
    above = np.array([[0.9, 0.0, 1.2]] * 20)  # 0.48 m above the table: seen through
    below = np.array([[0.9, 0.0, 0.3]] * 20)  # under it: hidden
    on = np.array([[0.9, 0.0, 0.725]] * 20)  # on it: there
    assert depth.seen_through(above, 0.02) == (20, 20)
    assert depth.seen_through(below, 0.02) == (0, 0)
    assert depth.seen_through(on, 0.02) == (0, 20)
    assert camera_above()[2, 3] == 2.6


def test_a_primitive_of_one_view_that_later_views_do_not_reproduce_goes():
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    # a sliver one view segmented on the table top (its points on the table's surface)
    sliver = box(1, (0.9, 0.0, 0.722), (0.12, 0.08, 0.004))
    mug = box(2, (0.5, 0.3, 0.77), (0.08, 0.08, 0.1))  # an object every view sees
    fusion = Fusion()
    fusion.update(observation(0, [table, sliver, mug]))
    assert len(fusion.prims) == 3
    went = [fusion.update(observation(k, [table, mug])).decayed for k in (1, 2, 3)]
    # three views saw the table where the sliver lay and matched nothing to it
    assert went == [0, 0, 1] and len(fusion.prims) == 2
    assert sorted(m.primitive.model.kind for m in fusion.prims.values()) == ["box", "plane"]
    # off: it stays; seen in two views: it stays
    cases = [
        (FusionConfig(unconfirmed_views=0), [[table, sliver, mug]]),
        (FusionConfig(), [[table, sliver, mug], [table, sliver, mug]]),
    ]
    for config, views in cases:
        fusion = Fusion(config)
        for k, prims in enumerate(views + [[table, mug]] * 4):
            fusion.update(observation(k, prims))
        assert len(fusion.prims) == 3


def test_each_group_is_judged_as_seen_through_judges_it_alone():
    table = plane(0, (0.2, 1.6), (-0.6, 0.6), 0.72)
    depth = ViewDepth(observation(0, [table]), 32)
    rng = np.random.default_rng(5)
    groups = [
        np.column_stack([rng.uniform(0.3, 1.5, n), rng.uniform(-0.5, 0.5, n), rng.uniform(0, 2, n)])
        for n in (1, 7, 40, 0, 150)
    ]
    through, evidence = depth.seen_through_each(groups, 0.02)
    alone = [depth.seen_through(g, 0.02) if len(g) else (0, 0) for g in groups]
    assert list(zip(through.tolist(), evidence.tolist(), strict=True)) == alone
    assert sum(t for t, _ in alone) > 20  # the groups do hold points seen through
