"""Whole exploration episodes, every service a process on a loopback router, the sim in
lockstep: the thesis's table-top (Fig. 4.8) and booth (Fig. 4.11, 4.12) experiments."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from itertools import pairwise

import numpy as np
import pytest

from tests.browser import layout
from tests.conftest import ROOT

AVS = [sys.executable, "-m", "avs.cli"]


def run(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    out = subprocess.run([*AVS, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr[-3000:]
    return out


def test_tabletop_occluded_support_graph_complete_by_view_5_and_ends_by_itself(tmp_path):
    """With the robot's sensor models and view registration, as ``avs run`` has them."""
    out = run(
        ["explore", "--scene", "tabletop_occluded", "--strategy", "utility", "--fusion", "sg",
         "--out", str(tmp_path)],
        timeout=600,
    )  # fmt: skip
    assert re.search(r" (\d+)/\1 terminated by quality", out.stderr), out.stderr  # progress
    m = json.loads((tmp_path / "metrics.json").read_text())
    views = m["views"]
    f1 = [v["support_f1"] for v in views]
    assert max(f1[:5]) >= 0.9, f1
    assert f1[0] < 0.9  # the first view cannot see what supports the occluded box
    assert m["terminated_by"] == "quality" and len(views) < 10  # it stopped by itself
    # the occluded support edges are found: the box behind the front one stands on the table
    edges = {tuple(e) for e in m["final_support_edges"]}
    assert ("table", "box_base") in edges and ("box_base", "cylinder_top") in edges
    unknown = [v["unknown_voxels"] for v in views]
    assert all(b < a for a, b in pairwise(unknown))
    cost = [v["accumulated_path_cost"] for v in views]
    assert cost[0] == 0 and all(b >= a for a, b in pairwise(cost))
    assert np.allclose(views[0]["base"], [0, 0, 0], atol=0.02)  # the first view: robot_start
    # the sensor models drift the odometry (the frames' believed poses 48 mm and 0.59° off the
    # truth at the 4th view measured); the scene memory's registration brings the pose the
    # map uses to 17.6 mm and 0.79° there (seed 0; 5.0, 3.6 and 3.8 mm with seeds 1-3)
    assert all(v["registration"] == "accepted" for v in views), views
    assert views[-1]["pose_error_m"] < 0.03 and views[-1]["pose_error_deg"] < 1.0, views[-1]
    # the report as a browser shows it: every view's colour image, the fused scene rendered, the
    # support graph drawn, the summary; nothing broken, nothing wider than a 1280 px window
    page = (tmp_path / "report.html").read_text()
    assert "stopped by" in page and "support F1 (precision, recall)" in page
    assert f"<td>{views[-1]['support_f1']:.2f} (" in page
    shown = layout(tmp_path / "report.html", tmp_path)
    assert shown["broken"] == [] and shown["width"] <= 1280, shown
    alts = shown["alts"]
    numbered = [f"view {i + 1}" for i in range(len(views))]  # as the plots number them
    assert [a for a in alts if a.startswith("view ")] == numbered
    assert {"fused_scene", "support_graph", "f1", "views_map", "information_gain"} <= set(alts)
    graph = m["final_support"]
    assert {e["verdict"] for e in graph} <= {"true", "false_positive", "not_judged"}
    assert sum(e["verdict"] == "true" for e in graph) >= 2


def test_the_kitchen_explores_from_a_start_boxed_in_by_unseen_floor(tmp_path):
    """The kitchen's first view sees the table behind the robot's back; every view of its
    view sphere lies past floor no view has seen, and the episode used to end there ("none
    of the 280 visible views has a collision-free path"). The robot looks around from where
    it stands, then drives: measured F1 0.71, 0.80, 0.80, 0.875 over four views (issue 43:
    ≥ 3 views, F1 ≥ 0.85 by the 6th), the wall behind the counter not on the counter."""
    run(["explore", "--scene", "kitchen", "--views", "4", "--out", str(tmp_path)], timeout=600)
    m = json.loads((tmp_path / "metrics.json").read_text())
    views = m["views"]
    assert len(views) == 4, m["terminated_by"]
    assert views[-1]["support_f1"] >= 0.85, [v["support_f1"] for v in views]
    edges = {tuple(e) for e in m["final_support_edges"]}
    assert ("tray", "apple") in edges and ("counter", "back_wall") not in edges
    moved = [np.linalg.norm(np.subtract(v["base"][:2], views[0]["base"][:2])) for v in views]
    assert max(moved) > 0.5  # it got away from where it started


def test_the_stack_on_a_shelfs_upper_board_is_resolved(tmp_path):
    """The open shelf (issue 43: a stack on the upper board was never resolved, recall 0.33):
    its boards and side panels meet at concave edges, which made "boxes" that swallowed the
    boards, and its front edges made a "plane" that seemed to hold the panels' tops. Measured
    2026-12-07: F1 0.40 before, 1.00 at every view after (five views)."""
    run(["explore", "--scene", "shelf", "--views", "5", "--out", str(tmp_path)], timeout=600)
    m = json.loads((tmp_path / "metrics.json").read_text())
    edges = {tuple(e) for e in m["final_support_edges"]}
    assert {("shelf", "box_base"), ("box_base", "cylinder_top"), ("shelf", "cup")} <= edges
    assert m["views"][-1]["support_f1"] >= 0.85, [v["support_f1"] for v in m["views"]]


def test_a_generated_shelf_is_explored_until_its_stack_is_resolved(tmp_path):
    """A generated shelf (``avs scene generate --shelf``, seed 2: box_1 on box_0 on the upper
    board, 96 cm up, two single objects beside them), five views: the stack's two support
    edges are in the final model and the support F1 is at least 0.85. Measured 2026-12-07:
    F1 0.89, 0.80, 1.00, 0.89, 0.89 over the views, the stack's edges found from the first.
    Not every generated shelf passes yet: on seed 1 the board's edge to the stack is lost at
    the fifth view (registration refused, the pose 32 mm off) and seed 3 stops after two
    views (by quality) without the stack's edge."""
    from services.sim.generate import generate

    scene = generate(2, shelf=True)
    path = tmp_path / "shelf_2.xml"
    path.write_text(scene.text)
    out = tmp_path / "episode"
    run(["explore", "--scene", str(path), "--views", "5", "--out", str(out)], timeout=600)
    m = json.loads((out / "metrics.json").read_text())
    edges = {tuple(e) for e in m["final_support_edges"]}
    bottom, top = scene.arrangements[0].objects
    assert {("table", bottom), (bottom, top)} <= edges, edges
    assert m["views"][-1]["support_f1"] >= 0.85, [v["support_f1"] for v in m["views"]]


@pytest.mark.timeout(1500)  # 15 episodes, two at a time: 2.5 minutes on a quiet machine
def test_booth_orderings_the_seeds_support(tmp_path):
    """Fig. 4.11 / 4.12, 5 views each, view spheres around the three meeting points, a 2 cm
    map, claiming only the orderings that the 95 % bootstrap intervals of the medians
    (``experiments/bootstrap.py``) support, computed by ``avs compare`` from these episodes.

    Over 10 seeds (``avs compare --seeds 10``, 2026-12-05, the episode driven by the explorer
    service in lockstep) the intervals support, for the unknown voxels in the roi after 5
    views, occupancy (4.234 M [4.230, 4.237]) < utility (4.306 M [4.291, 4.327]) < random
    (4.474 M [4.370, 4.635]), and for the accumulated path cost utility (21.5 s [19.2, 21.8])
    < occupancy (28.4 s [28.1, 29.2]). They do not resolve random (21.4 s [17.0, 29.9])
    against either on path cost (a random placement's drives vary from 12 to 35 s), nor any
    ordering of the support F1.

    This test runs 5 seeds to stay within the suite's time (at 3 the interval of a median
    cannot reach its level and ``avs compare`` supports nothing). At seeds 0-4 (the episode
    driven by the explorer service in lockstep) the same bootstrap supports occupancy <
    utility and occupancy < random on unknown voxels and utility < occupancy on path cost,
    which it asserts; utility < random on unknown voxels needs more seeds (one random seed of
    five ends at 4.295 M, inside utility's interval 4.303-4.329 M) and is not claimed, nor is
    random < occupancy on path cost (random's interval is 16.9-35.3 s at 5)."""
    out = run(
        ["compare", "--scene", "booth", "--strategies", "utility,occupancy,random",
         "--seeds", "5", "--views", "5", "--voxel", "0.02", "--jobs", "2", "--out", str(tmp_path)],
        timeout=1500,
    )  # fmt: skip
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    runs = metrics["runs"]
    assert set(runs) == {"utility", "occupancy", "random"}
    for episodes in runs.values():
        assert [e["seed"] for e in episodes] == [0, 1, 2, 3, 4]
        assert all(len(e["views"]) == 5 for e in episodes)
        for e in episodes:  # every strategy explores: fewer unknown voxels after each view
            u = [v["unknown_voxels"] for v in e["views"]]
            assert all(b <= a for a, b in pairwise(u)) and u[-1] < 0.9 * u[0]
    summary = metrics["summary"]
    for strategy, episodes in runs.items():  # the summary is of these episodes' last views
        for metric, s in summary[strategy].items():
            values = [e["views"][-1][metric] for e in episodes]
            assert s["n"] == 5 and s["median"] == pytest.approx(float(np.median(values)))
            assert min(values) <= s["ci95"][0] <= s["median"] <= s["ci95"][1] <= max(values)
    supported = {(o["metric"], o["better"], o["worse"])
                 for o in metrics["orderings"] if o["supported"]}  # fmt: skip
    claimed = {
        ("unknown_voxels", "occupancy", "utility"),
        ("unknown_voxels", "occupancy", "random"),
        ("accumulated_path_cost", "utility", "occupancy"),
    }
    assert claimed <= supported, (supported, summary)
    for metric, better, worse in claimed:  # supported: the intervals lie apart
        assert summary[better][metric]["ci95"][1] < summary[worse][metric]["ci95"][0]
    print("\n".join(out.stdout.splitlines()[:6]))
    (said,) = [line for line in out.stdout.splitlines() if line.startswith("supported")]
    assert "unknown voxels: occupancy < utility" in said and "path cost: utility <" in said
    assert (tmp_path / "report.html").is_file()
    for name in ("f1.png", "unknown_voxels.png", "path_cost.png", "views_map.png",
                 "information_gain.png"):  # fmt: skip
        assert (tmp_path / name).stat().st_size > 1000


def test_compare_fusion_modes_keys_runs_strategy_slash_fusion_and_plots_f1_per_view(tmp_path):
    """``--fusion sg,pc``: every strategy runs with each mode, runs keyed strategy/fusion with
    an episode directory each, and fusion_f1.png / .json give F1 per view (Fig. 4.8). Kept
    cheap: one seed, two views, a 2 cm map, two episodes side by side."""
    out = run(
        ["compare", "--scene", "tabletop_occluded", "--strategies", "random", "--fusion",
         "sg,pc", "--seeds", "1", "--views", "2", "--voxel", "0.02", "--jobs", "2",
         "--out", str(tmp_path)],
        timeout=300,
    )  # fmt: skip
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    runs = metrics["runs"]
    assert list(runs) == ["random/sg", "random/pc"]
    # one seed: each median is its episode's, with nothing to resample
    for k in runs:
        f1 = runs[k][0]["views"][-1]["support_f1"]
        assert metrics["summary"][k]["support_f1"] == {"median": f1, "ci95": [f1, f1], "n": 1}
    metrics_compared = {"support_f1", "unknown_voxels", "accumulated_path_cost"}
    assert {o["metric"] for o in metrics["orderings"]} == metrics_compared
    assert "95 % bootstrap interval" in out.stdout and "not resolved" in out.stdout
    assert [e["fusion"] for k in runs for e in runs[k]] == ["sg", "pc"]
    assert all(len(e["views"]) == 2 for k in runs for e in runs[k])
    assert (tmp_path / "random-sg-0" / "floor.png").is_file()
    assert (tmp_path / "random-pc-0" / "floor.png").is_file()
    numbers = json.loads((tmp_path / "fusion_f1.json").read_text())
    assert set(numbers) == set(runs)
    for k, n in numbers.items():
        assert (n["strategy"], n["fusion"]) == tuple(k.split("/"))
        assert n["views"] == [1, 2] and n["episodes_at_view"] == [1, 1]
        f1 = [v["support_f1"] for v in runs[k][0]["views"]]
        assert n["median"] == n["min"] == n["max"] == [round(v, 4) for v in f1]
    # pc re-extracts from the registered cloud of the roi: the start view's scene at least
    assert numbers["random/pc"]["median"][0] > 0.5, numbers
    assert (tmp_path / "fusion_f1.png").stat().st_size > 10_000
    assert "random/pc" in out.stdout and "fusion_f1" in (tmp_path / "report.html").read_text()
    # each episode's views with their images (in the episode's directory), each mode's scene
    alts = layout(tmp_path / "report.html", tmp_path)["alts"]
    assert [a for a in alts if a.startswith("view ")] == ["view 1", "view 2"] * 2, alts
    assert {"fused_scene_0", "support_graph_0", "fused_scene_1", "support_graph_1"} <= set(alts)
