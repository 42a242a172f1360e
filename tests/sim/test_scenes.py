"""Scenes: every built-in compiles with both robots and steps without a MuJoCo warning; the
ground-truth support graph is the hand-written one; bad scene files get one clear line."""

from __future__ import annotations

import json
import subprocess
import sys

import mujoco
import numpy as np
import pytest

from services.sim.ground_truth import support_graph
from services.sim.robots import ROBOTS
from services.sim.scene import BUILTIN_SCENES, SceneError
from services.sim.world import World
from tests.conftest import ROOT


@pytest.mark.parametrize("robot", sorted(ROBOTS))
@pytest.mark.parametrize("scene", BUILTIN_SCENES)
def test_builtin_scene_compiles_and_steps_without_warnings(scene, robot):
    world = World(scene, ROBOTS[robot])
    bodies = [world.model.body(n).id for n in world.info.objects]
    start = world.data.xpos[bodies].copy(), world.data.xquat[bodies].copy()
    world.step(1000)
    warnings = {
        mujoco.mjtWarning(i).name: int(w.number)
        for i, w in enumerate(world.data.warning)
        if w.number
    }
    assert warnings == {}
    assert world.info.roi is not None
    # objects stay at rest: under 1 mm and 0.5° in a second
    moved = np.linalg.norm(world.data.xpos[bodies] - start[0], axis=1)
    turned = 2 * np.arccos(np.minimum(1, np.abs(np.sum(world.data.xquat[bodies] * start[1], 1))))
    assert moved.max(initial=0) < 1e-3 and np.degrees(turned).max(initial=0) < 0.5


def test_booth_has_three_points_of_interest():
    assert sorted(World("booth", ROBOTS["armar6"]).info.pois) == ["poi_1", "poi_2", "poi_3"]


EXPECTED_EDGES = {
    "tabletop_occluded": {
        ("floor", "table"),
        ("table", "box_front"),
        ("table", "box_base"),
        ("table", "cup"),
        ("box_base", "cylinder_top"),
    },
    "tabletop_clutter": {
        ("floor", "table"),
        ("table", "crate"),
        ("table", "book_stack"),
        ("table", "can"),
        ("table", "ball"),
        ("table", "bottle"),
        ("table", "book"),
        ("crate", "can_on_crate"),
        ("book_stack", "box_small"),
    },
    "shelf": {
        ("floor", "shelf"),
        ("shelf", "box_base"),
        ("shelf", "cup"),
        ("box_base", "cylinder_top"),
    },
}


def _transitive(edges: set[tuple[str, str]]) -> set[tuple[str, str]]:
    out = set(edges)
    changed = True
    while changed:
        new = {(a, d) for a, b in out for c, d in out if b == c} - out
        changed = bool(new)
        out |= new
    return out


@pytest.mark.parametrize("scene", sorted(EXPECTED_EDGES))
def test_ground_truth_support_graph_is_the_hand_written_one(scene):
    world = World(scene, ROBOTS["armar6"])
    edges, closure = support_graph(world.model, world.data, world.info)
    assert set(edges) == EXPECTED_EDGES[scene]
    assert set(closure) == _transitive(EXPECTED_EDGES[scene])


BAD_SCENES = {
    "not_mjcf.xml": ("this is not xml <", "not a valid MuJoCo MJCF file"),
    "no_start.xml": (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/></worldbody></mujoco>',
        "has no site named robot_start",
    ),
    "capsule.xml": (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<site name="robot_start"/><body name="pill" pos="2 0 0.2"><freejoint/>'
        '<geom type="capsule" size="0.05 0.1"/></body></worldbody></mujoco>',
        "free body 'pill' has a capsule geom",
    ),
    "overlap.xml": (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<site name="robot_start"/>'
        '<body name="a" pos="2 0 0.1"><freejoint/><geom type="box" size=".1 .1 .1"/></body>'
        '<body name="b" pos="2.1 0 0.1"><freejoint/><geom type="box" size=".1 .1 .1"/></body>'
        "</worldbody></mujoco>",
        "objects start interpenetrating: 'a' and 'b'",
    ),
    "robot_in_table.xml": (
        '<mujoco><worldbody><geom name="floor" type="plane" size="5 5 .1"/>'
        '<site name="robot_start" pos="0.2 0 0"/>'
        '<body name="desk"><geom type="box" size=".3 .3 .4" pos="0.5 0 0.4"/></body>'
        "</worldbody></mujoco>",
        "the robot at robot_start overlaps 'desk'",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD_SCENES))
def test_bad_scene_files_are_refused_with_one_line(tmp_path, name):
    text, problem = BAD_SCENES[name]
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(SceneError, match=problem):
        World(path, ROBOTS["armar6"])
    out = subprocess.run(
        [sys.executable, "-m", "avs.cli", "sim", "--scene", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
    )
    assert out.returncode == 2
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert str(path) in lines[0] and problem in lines[0]


def test_unknown_scene_names_the_built_ins():
    with pytest.raises(SceneError, match=r"no such built-in scene.*tabletop_clutter"):
        World("tabletop_clutterr", ROBOTS["armar6"])


def test_ground_truth_command_prints_the_json_the_issue_asks_for():
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "avs.cli",
            "sim",
            "ground-truth",
            "--scene",
            "tabletop_occluded",
            "--json",
        ],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )
    assert out.returncode == 0, out.stderr
    gt = json.loads(out.stdout)
    assert {"objects", "support_edges", "support_closure"} <= set(gt)
    assert {tuple(e) for e in gt["support_edges"]} == EXPECTED_EDGES["tabletop_occluded"]
    cup = next(o for o in gt["objects"] if o["name"] == "cup")
    assert cup["kind"] == "cylinder" and cup["size"] == pytest.approx([0.08, 0.08, 0.11])
    assert len(cup["pose"]) == 4 and len(cup["pose"][0]) == 4
