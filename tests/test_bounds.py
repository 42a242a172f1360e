"""The map's bounds come from the robot's world: roi, start, the view spheres' platform poses
and the workspace (avs/bounds.py)."""

from __future__ import annotations

import numpy as np

from avs.bounds import CEILING_Z, FLOOR_Z, map_bounds
from experiments.episode import scene_facts

ROI = (np.array([1.0, -0.5, 0.7]), np.array([1.8, 0.5, 1.1]))
CENTRE = np.array([[1.4, 0.0, 0.9]])


def _inside(p, lo, hi) -> bool:
    return bool(np.all(lo[: len(p)] <= p) and np.all(p <= hi[: len(p)]))


def test_the_map_covers_start_roi_and_every_view_platform_pose():
    start = (-2.5, 1.0)
    lo, hi = map_bounds(ROI, start, CENTRE, radius=1.5, footprint=0.45, margin=0.3)
    assert _inside(ROI[0], lo, hi) and _inside(ROI[1], lo, hi)
    # the whole footprint at the start, with its margin
    for d in ([0.75, 0], [-0.75, 0], [0, 0.75], [0, -0.75]):
        assert _inside(np.array(start) + d, lo, hi)
    # every platform pose on the view sphere (Eq. 4.2: within r of the centre), footprint too
    for a in np.linspace(0, 2 * np.pi, 37):
        p = CENTRE[0, :2] + 1.5 * np.array([np.cos(a), np.sin(a)])
        assert _inside(p + 0.7 * np.array([np.cos(a), np.sin(a)]), lo, hi)
    assert lo[2] == FLOOR_Z and hi[2] >= CEILING_Z
    # and no bigger than that: the start's side ends at its footprint
    assert lo[0] == -2.5 - 0.75


def test_a_workspace_bounds_the_view_poses_and_is_covered():
    workspace = (np.array([0.5, -1.0, 0.0]), np.array([2.5, 3.0, 1.0]))
    lo, hi = map_bounds(ROI, (1.0, 0.0), CENTRE, workspace=workspace, margin=0.3)
    # the view sphere's poses reach x -0.1..2.9: clipped to the workspace (+ the footprint)
    assert lo[0] == 0.5 - 0.75 and hi[0] == 2.5 + 0.75
    assert lo[1] == -1.0 - 0.75  # and y -1.5..1.5: below, clipped too
    assert hi[1] == 3.0  # above, the workspace itself reaches further


def test_scene_facts_of_a_far_start_put_the_robot_on_the_map(tmp_path):
    scene = tmp_path / "far.xml"
    scene.write_text(
        '<mujoco><worldbody><geom name="floor" type="plane" size="6 6 .1"/>'
        '<body name="table"><geom type="box" size=".4 .6 .36" pos="1.3 0 .36"/></body>'
        '<body name="cup" pos="1.3 0 .78"><freejoint/><geom type="cylinder" size=".04 .05"/>'
        '</body><site name="robot_start" pos="-2.2 1.5 0" euler="0 0 180"/>'
        '<site name="roi" type="box" pos="1.3 0 .85" size=".45 .65 .15"/></worldbody></mujoco>'
    )
    facts = scene_facts(str(scene), "armar6")
    assert _inside(np.array([-2.2 - 0.45, 1.5 + 0.45]), facts.map_min, facts.map_max)
    assert facts.start[2] == np.pi or abs(abs(facts.start[2]) - np.pi) < 1e-6
