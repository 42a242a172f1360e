"""Support read off the fused geometry (``services/scene_memory/stability.py``): what stands on
the floor, lies on a level top (tilted, or seen only in part) or touches something stable
from above is stable; what hovers, stands beside, or touches only at its side is not."""

from __future__ import annotations

import numpy as np

from schemas import Obb, PlaneModel, Primitive
from services.scene_memory.fusion import Fusion
from services.scene_memory.stability import Body, StabilityConfig, floor_height, settle
from tests.scene_memory.builders import box, cylinder, observation, plane
from tests.scene_memory.test_evidence import wall

C = StabilityConfig()


def _bodies(*prims: Primitive) -> dict[int, Body]:
    return {p.id: Body(p, np.asarray(p.inliers, float)) for p in prims}


def tilted(pid: int, x: tuple[float, float], y: tuple[float, float], z: float, deg: float):
    """A level-ish rectangle rising ``deg`` along x, through (x mid, y mid, z)."""
    rng = np.random.default_rng(pid)
    n, xm = 2000, sum(x) / 2
    px, py = rng.uniform(*x, n), rng.uniform(*y, n)
    slope = np.tan(np.radians(deg))
    pts = np.column_stack([px, py, z + slope * (px - xm)])
    normal = np.array([-slope, 0.0, 1.0]) / np.hypot(slope, 1.0)
    c = np.array([xm, sum(y) / 2, z])
    a = np.radians(deg)
    R = np.array([[np.cos(a), 0, -np.sin(a)], [0, 1, 0], [np.sin(a), 0, np.cos(a)]])
    return Primitive(
        id=pid,
        model=PlaneModel(normal=normal, d=-float(normal @ c)),
        obb=Obb(center=c, rotation=R, extent=np.array([x[1] - x[0], y[1] - y[0], 0.004])),
        inlier_count=n,
        inliers=pts.astype(np.float32),
    )


def test_what_reaches_the_floor_stands_on_it_wherever_the_floor_was_seen():
    floor = plane(0, (0.0, 1.0), (0.0, 1.0), 0.0)  # seen only here
    standing = box(1, (3.0, 2.0, 0.2), (0.2, 0.2, 0.4))  # 2 m away, on the floor
    hovering = box(2, (3.0, 0.0, 0.3), (0.2, 0.2, 0.4))  # 10 cm above it
    bodies = _bodies(floor, standing, hovering)
    assert abs(floor_height(bodies, C)) < 0.005
    assert settle(bodies, {0}, {}, C)[1] == {1: ("floor", None)}
    # a table top is no floor: the lowest large level plane at 0.72 m stands on nothing
    table = plane(0, (0.0, 1.0), (0.0, 1.0), 0.72)
    assert floor_height(_bodies(table), C) is None
    assert settle(_bodies(table, box(1, (3.0, 2.0, 0.92), (0.2, 0.2, 0.4))), {0}, {}, C)[1] == {}


def test_mugs_at_both_ends_of_a_tilted_table_rest_on_it():
    # a 2.4 m table 2° off level (a gravity estimate's error): its ends are 3.8 cm below and
    # above its centre; its box's top, 4.2 cm above the centre, is 8 cm above the low end
    table = tilted(0, (0.0, 2.4), (0.0, 0.8), 0.72, 2.0)
    rise = np.tan(np.radians(2.0)) * 1.1
    low = cylinder(1, (0.1, 0.4, 0.72 - rise), 0.04, 0.1, 0.0)
    high = cylinder(2, (2.3, 0.4, 0.72 + rise), 0.04, 0.1, 0.0)
    hover = cylinder(3, (2.1, 0.4, 0.72 + rise + 0.08), 0.04, 0.1, 0.0)
    got = settle(_bodies(table, low, high, hover), {0}, {}, C)[1]
    assert got == {1: ("level", 0), 2: ("level", 0)}, got


def test_a_book_at_the_back_of_a_counter_seen_only_at_its_front_rests_on_it():
    counter = plane(0, (0.0, 0.3), (0.0, 2.0), 0.88)  # the sensor saw its front 30 cm
    at_back = box(1, (0.35, 1.0, 0.98), (0.16, 0.3, 0.2))  # its base reaches 3 cm over
    beyond = box(2, (0.45, 0.5, 0.98), (0.1, 0.3, 0.2))  # 10 cm past the seen edge
    assert settle(_bodies(counter, at_back, beyond), {0}, {}, C)[1] == {1: ("level", 0)}


def test_contact_from_below_supports_and_contact_at_the_side_does_not():
    floor = plane(0, (-1.0, 3.0), (-1.0, 1.0), 0.0)
    ramp = tilted(1, (0.8, 1.2), (-0.2, 0.2), 0.3, 30.0)  # no level top to lie on
    # the box's edge at x = 0.95 on the ramp, where the ramp is highest under it
    foot = 0.3 - np.tan(np.radians(30.0)) * 0.05
    resting = box(2, (0.9, 0.0, foot + 0.05), (0.1, 0.1, 0.1))
    beside = box(3, (0.7, 0.6, 0.5), (0.1, 0.1, 0.2))  # nothing below it
    the_wall = wall(4, (-1.0, 1.0), 0.8, (0.0, 1.6))  # touches 3 at its side
    bodies = _bodies(floor, ramp, resting, beside, the_wall)
    got = settle(bodies, {0, 1, 4}, {}, C)[1]
    assert got == {2: ("contact", 1)}, got  # 3: its side touches the wall, nothing below


def test_the_memory_marks_stable_what_the_geometry_holds_without_seen_edges():
    floor = plane(0, (0.0, 1.0), (-1.0, 1.0), 0.0)
    table = tilted(1, (0.2, 2.2), (-0.5, 0.5), 0.72, 2.0)
    far_end = 0.72 + np.tan(np.radians(2.0)) * 0.95
    mug = cylinder(2, (2.15, 0.0, far_end), 0.04, 0.1, np.pi)
    chair = box(3, (2.0, 1.0, 0.23), (0.4, 0.4, 0.46))  # on the floor, far from its patch
    lamp = box(4, (1.2, 0.0, 1.3), (0.2, 0.2, 0.2))  # hangs in the air: unstable
    fusion = Fusion()
    fusion.update(observation(0, [floor, table, mug, chair, lamp]))  # no support edges
    model = fusion.scene_model()
    z = {round(float(p.obb.center[2]), 2): p.id for p in model.primitives}
    # the lamp alone is not stable (unstable where the view saw the table past its base's
    # edge, else unresolved: from straight above a box hides what is under it)
    assert sorted(model.unstable_ids + model.unresolved_ids) == [z[1.3]], (model, z)
    rules = {rule for rule, _ in fusion.settled.values()}
    assert rules == {"floor", "level"}, fusion.settled
