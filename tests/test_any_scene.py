"""Scenes nobody here wrote: a user's desk in the documented format with default-styled sites
and unnamed furniture, a start far away facing the wrong way, the built-in localization
scene, and generated scenes. Each runs through the commands a user runs."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from services.sim import capture
from services.sim.render import CameraRenderer
from services.sim.robots import ROBOTS
from services.sim.world import World
from tests.conftest import ROOT

#: a desk as a user writes one: unnamed static geoms, sites as MuJoCo draws them by default
DESK = """<mujoco model="my_desk">
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" size="6 6 0.1"/>
    <geom type="box" size="0.4 0.6 0.02" pos="1.3 0 0.7"/>
    <geom type="box" size="0.35 0.55 0.34" pos="1.3 0 0.34"/>
    <body name="mug" pos="1.15 -0.25 0.78"><freejoint/>
      <geom type="cylinder" size="0.04 0.06" rgba="0.9 0.2 0.2 1"/></body>
    <body name="carton" pos="1.3 0.1 0.82"><freejoint/>
      <geom type="box" size="0.06 0.09 0.1" rgba="0.2 0.4 0.9 1"/></body>
    <body name="orange" pos="1.2 0.35 0.76"><freejoint/>
      <geom type="sphere" size="0.04" rgba="1 0.6 0.1 1"/></body>
    <site name="robot_start" pos="{start}" euler="0 0 {yaw}"/>
    <site name="roi" type="box" pos="1.3 0 0.85" size="0.45 0.65 0.2"/>
    <site name="poi_desk" pos="1.3 0 0.8"/>{extra}
  </worldbody>
</mujoco>
"""


def desk(tmp_path: Path, start: str = "0 0 0", yaw: float = 0.0, extra: str = "") -> Path:
    path = tmp_path / f"desk_{abs(hash((start, yaw, extra)))}.xml"
    path.write_text(DESK.format(start=start, yaw=yaw, extra=extra))
    return path


def avs(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "avs.cli", *args],
        capture_output=True, text=True, timeout=timeout, cwd=ROOT,
    )  # fmt: skip


def test_sites_are_markers_that_no_camera_sees(tmp_path):
    """Default-styled roi / poi sites and a large box site: the depth image is the one of
    the same scene without them, and every in-range return belongs to a geom."""
    big = '\n    <site name="marker" type="box" pos="1.0 0 1.0" size="0.3 0.3 0.3"/>'
    with_sites = desk(tmp_path, extra=big)
    bare = tmp_path / "bare.xml"
    lines = with_sites.read_text().splitlines()
    bare.write_text("\n".join(x for x in lines if "<site" not in x or "robot_start" in x))
    depths = []
    for path in (with_sites, bare):
        world = World(path, ROBOTS["armar6"])
        world.face(np.array([1.3, 0.0, 0.85]))
        renderer = CameraRenderer(world.model, 320, 240)
        frame, _ = capture.view(world, renderer, "head_rgbd", None)
        depths.append(frame.depth)
        assert capture.unowned_depth_fraction(world, renderer, "head_rgbd", frame.depth) == 0.0
        renderer.close()
    assert (depths[0] > 0).mean() > 0.5
    np.testing.assert_array_equal(depths[0], depths[1])


@pytest.mark.parametrize("start, yaw", [("0 0 0", 0), ("0.1 0.4 0", 150)])
def test_perceive_a_user_scene(tmp_path, start, yaw):
    """One view from robot_start (facing away: the platform turns in place first)."""
    out = avs("perceive", "--scene", str(desk(tmp_path, start, yaw)), "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["unowned_depth_fraction"] <= 0.005
    assert d["inlier_index"] >= 0.9, d["inlier_index"]
    assert {"mug", "carton", "orange"} <= set(d["primitive_bodies"].values())


def _episode(out: Path, *args: str) -> tuple[dict, subprocess.CompletedProcess]:
    run = avs("explore", *args, "--out", str(out), timeout=600)
    assert run.returncode == 0, run.stderr[-3000:]
    logs = "".join(f.read_text() for f in sorted((out / "logs").glob("*.log")))
    for text in (run.stderr, logs):  # the console, and the services' logs
        assert "Traceback" not in text and "nanobind: leaked" not in text
    return json.loads((out / "metrics.json").read_text()), run


@pytest.mark.timeout(600)
def test_explore_from_far_away_facing_away(tmp_path):
    """The robot starts 2.5 m from the roi, facing away: the map covers it, the first view
    turns the platform toward the scene, and the episode goes on."""
    scene = desk(tmp_path, start="-1.65 0.3 0", yaw=180)
    # on the simulator's truth, with view registration: the views after the first overlap
    # the map too little to register (the desk seen thinly from 2.5 m, then from its sides),
    # and registration must say so and keep the pose, not slide it along the desk (it once
    # moved the true pose 38 mm). With the sensor models the 2 m drive leaves the odometry
    # 7 cm off, which no view here can correct: a known limit, services/scene_memory/README.md
    m, _ = _episode(tmp_path / "far", "--scene", str(scene), "--views", "3", "--noise", "off",
                    "--registration", "on")  # fmt: skip
    views = m["views"]
    assert all(v["pose_error_m"] < 0.002 and v["pose_error_deg"] < 0.1 for v in views), views
    assert len(views) >= 3, (m["terminated_by"], m["termination_detail"])
    first = views[0]
    assert first["path_cost"] > 2.5  # turned about 170° at 1 rad/s
    assert abs(first["base"][2] - np.arctan2(-0.3, 2.95)) < 0.05
    # every object is found on the desk top; the desk's top on its base (two static geoms
    # the ground truth tells apart) is what the views leave out
    edges = {tuple(e) for e in m["final_support_edges"]}
    assert {("geom_1", "mug"), ("geom_1", "carton"), ("geom_1", "orange")} <= edges
    assert views[-1]["support_f1"] >= 0.8 and views[-1]["inlier_index"] >= 0.85


@pytest.mark.timeout(600)
def test_explore_localization_goes_past_its_first_view(tmp_path):
    m, _ = _episode(tmp_path / "loc", "--scene", "localization", "--views", "4")
    assert len(m["views"]) >= 3, (m["terminated_by"], m["termination_detail"])
    assert m["views"][-1]["support_f1"] == 1.0


@pytest.mark.parametrize("seed", [1000, 1003, 1012])
def test_perceive_generated_scenes(tmp_path, seed):
    scene = tmp_path / f"scene_{seed}.xml"
    assert avs("scene", "generate", "--seed", str(seed), "--out", str(scene)).returncode == 0
    out = avs("perceive", "--scene", str(scene), "--json")
    assert out.returncode == 0, out.stderr
    d = json.loads(out.stdout)
    assert d["unowned_depth_fraction"] == 0.0 and d["inlier_index"] >= 0.85


@pytest.mark.timeout(600)
def test_explore_a_generated_scene(tmp_path):
    """A bridge (a plank on two boxes) and a sphere; honest scoring: every fused edge
    counts, the final graph is the ground truth's."""
    scene = tmp_path / "scene_1012.xml"
    assert avs("scene", "generate", "--seed", "1012", "--out", str(scene)).returncode == 0
    m, _ = _episode(tmp_path / "gen", "--scene", str(scene), "--views", "3")
    assert len(m["views"]) >= 2
    final = m["views"][-1]
    assert final["support_f1"] >= 0.9, m["final_support_edges"]
    assert {("box_0", "plank_2"), ("box_1", "plank_2")} <= {
        tuple(e) for e in m["final_support_edges"]
    }


@pytest.mark.timeout(600)
def test_a_goal_behind_glass_is_abandoned_and_the_episode_goes_on(tmp_path):
    """A glass pane behind the desk (1.6 m wide): a geom in group 3, which no sensor renders
    but the platform collides with. The views behind the desk look free to the planner; the
    straight path there runs the platform's footprint into the pane's end, where it stands
    pushing. The explorer abandons the goal after twice its estimated time (plus a margin):
    the next plan excludes it and its paths go round where the platform got stuck, and the
    episode goes on to take its views."""
    pane = '\n    <geom name="glass" type="box" size="0.01 0.8 1" pos="2.0 0 1" group="3"/>'
    m, _ = _episode(tmp_path / "glass", "--scene", str(desk(tmp_path, extra=pane)),
                    "--views", "4")  # fmt: skip
    views = m["views"]
    assert m["abandoned_goals"] >= 1, [v["goal"] for v in views]
    # views were taken after an abandoned goal: the episode went on, round the pane
    assert any(v["abandoned"] > 0 for v in views), views
    assert m["terminated_by"] in ("max_views", "quality"), m["termination_detail"]
    assert len(views) == 4 or m["terminated_by"] == "quality"
    assert views[-1]["support_f1"] >= 0.8
