"""The report's pictures (experiments/scene_figures.py, experiments/report.py): the fused scene
rendered where the labels say, the support graph's layout and verdicts, the page in a browser."""

from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from experiments import report, scene_figures
from experiments.scene_figures import project, scene_xml, support_levels, view_of
from tests.browser import layout

ROI = [[0.85, -0.65, 0.75], [1.75, 0.65, 1.15]]


def primitives() -> list[dict]:
    eye = np.eye(3).tolist()
    return [
        {"id": 1, "kind": "plane", "body": "table", "center": [1.3, 0.0, 0.75],
         "extent": [0.8, 1.2, 0.01], "rotation": eye, "colour": [0.5, 0.5, 0.5]},
        {"id": 2, "kind": "box", "body": "box_0", "center": [1.2, 0.25, 0.85],
         "extent": [0.2, 0.2, 0.2], "rotation": eye, "colour": [0.9, 0.05, 0.05]},
        {"id": 3, "kind": "cylinder", "body": "cup", "center": [1.4, -0.25, 0.81],
         "extent": [0.08, 0.08, 0.12], "rotation": eye, "colour": [0.05, 0.1, 0.9],
         "model": {"center": [1.4, -0.25, 0.81], "axis": [1.0, 0.0, 0.0], "radius": 0.04,
                   "height": 0.12}, "state": "unresolved"},
    ]  # fmt: skip


def test_the_solids_are_the_primitives_geometry():
    import mujoco

    model = mujoco.MjModel.from_xml_string(scene_xml(primitives()))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    assert model.ngeom == 3
    types = [mujoco.mjtGeom(t).name for t in model.geom_type]
    assert types == ["mjGEOM_BOX", "mjGEOM_BOX", "mjGEOM_CYLINDER"]
    assert np.allclose(model.geom_size[0], [0.4, 0.6, 0.005])  # a plane: ≥ 1 cm thick
    assert np.allclose(model.geom_size[2][:2], [0.04, 0.06])  # radius, half height
    axis = data.geom_xmat[2].reshape(3, 3)[:, 2]  # the cylinder's z: its fitted axis
    assert np.allclose(np.abs(axis), [1, 0, 0], atol=1e-6)


def test_a_point_at_the_lookat_projects_to_the_centre_and_right_is_right():
    view = view_of(ROI, azimuth=180.0, elevation=-30.0)  # from +x, looking towards −x
    size = (800, 600)
    centre, right = project(np.array([view[0], view[0] + [0.0, 0.1, 0.0]]), view, size, 45.0)
    assert np.allclose(centre, [400, 300], atol=1e-6)
    # looking along −x, +y is to the camera's right: further right in the image
    assert right[0] > centre[0] + 5 and abs(right[1] - centre[1]) < 1


@pytest.mark.timeout(120)
def test_the_rendering_shows_each_solid_where_its_label_is(tmp_path):
    """The labels are placed by ``project``; MuJoCo renders the solids: at the red box's
    projected centre the image is red, at the blue cylinder's blue."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import mujoco

    prims = primitives()
    view, size = view_of(ROI), (480, 360)
    model = mujoco.MjModel.from_xml_string(scene_xml(prims))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    camera = mujoco.MjvCamera()
    camera.type = mujoco.mjtCamera.mjCAMERA_FREE
    camera.lookat[:], camera.distance, camera.azimuth, camera.elevation = view
    with mujoco.Renderer(model, size[1], size[0]) as renderer:
        renderer.update_scene(data, camera)
        image = renderer.render().astype(int)
    fovy = float(model.vis.global_.fovy)
    (ub, vb), (uc, vc) = project(np.array([prims[1]["center"], prims[2]["center"]]), view, size,
                                 fovy)  # fmt: skip
    r, g, b = image[round(vb), round(ub)]
    assert r > 2 * g and r > 2 * b, (r, g, b)
    r, g, b = image[round(vc), round(uc)]
    assert b > 2 * r and b > g, (r, g, b)
    path = scene_figures.scene_image(prims, ROI, tmp_path)
    assert path.name == "fused_scene.png" and path.stat().st_size > 10_000


def test_support_levels_stack_what_stands_on_what_and_survive_a_cycle():
    levels = support_levels([1, 2, 3, 4], [(1, 2), (2, 3), (1, 4)])
    assert levels == {1: 0, 2: 1, 3: 2, 4: 1}
    cyclic = support_levels([1, 2], [(1, 2), (2, 1)])
    assert set(cyclic) == {1, 2} and max(cyclic.values()) <= 1


def test_each_support_edge_gets_its_verdict():
    edges = [SimpleNamespace(supporter=1, supported=2, occ=3),
             SimpleNamespace(supporter=2, supported=9, occ=1),
             SimpleNamespace(supporter=7, supported=8, occ=2)]  # fmt: skip
    bodies = {1: "table", 2: "box_0", 7: "shelf", 8: "vase"}
    scores = SimpleNamespace(edges=[("table", "box_0"), ("box_0", "#9")],
                             false_positives=[("box_0", "#9")])  # fmt: skip
    out = scene_figures.support_verdicts(edges, bodies, scores)
    assert [e["verdict"] for e in out] == ["true", "false_positive", "not_judged"]
    assert out[1]["bodies"] == ["box_0", "#9"] and out[0]["occ"] == 3


@pytest.mark.timeout(180)
def test_a_report_in_a_browser_has_every_picture_and_fits_1280_px(tmp_path):
    """A canned episode (three views): the page holds a thumbnail per view, the rendering,
    the graph and the plots; Chromium loads every image and lays the page out within
    1280 px. A page that overflows, or an image that does not load, fails."""
    rng = np.random.default_rng(0)
    views = []
    for i in range(3):
        rgb = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
        T = np.eye(4)
        T[:3, :3] = np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]]).T  # optical z along +x
        views.append({
            "view": i, "support_f1": 0.5 + 0.2 * i, "support_precision": 0.8,
            "support_recall": 0.6, "unknown_voxels": 40_000 - 10_000 * i,
            "information_gain": [0, 12_000, 3_000][i],
            "realised_gain": [428_943, 9_000, 2_000][i], "path_cost": 3.0 * i,
            "accumulated_path_cost": 4.5 * i, "planning_s": 1.2, "base": [0.1 * i, 0.0, 0.0],
            "inlier_index": 0.95, "overlapping_index": 0.1, "camera_pose_used": T.tolist(),
            "rgb": scene_figures.thumbnail(rgb, tmp_path / "views" / f"view_{i + 1}.jpg",
                                           tmp_path),
        })  # fmt: skip
    support = [{"supporter": 1, "supported": 2, "occ": 3, "bodies": ["table", "box_0"],
                "verdict": "true"}]  # fmt: skip
    e = {"scene": "tabletop_clutter", "strategy": "utility", "sampling": "equidistant",
         "fusion": "sg", "seed": 0, "robot": "armar6", "views": views, "roi": ROI,
         "centre": [1.3, 0.0, 0.95], "terminated_by": "quality", "camera_hfov_deg": 60.0,
         "final_primitives": primitives(), "final_support": support,
         "final_missed": [["table", "cup"]]}  # fmt: skip
    images = [*report.series_plots({"utility": [e]}, tmp_path),
              report.map_plot({"utility": e}, tmp_path)]  # fmt: skip
    page = report.html_report("tabletop_clutter", images, {"utility seed 0": e}, tmp_path)
    text = page.read_text()
    assert "stopped by" in text and "0.90 (0.80, 0.60)" in text
    shown = layout(page, tmp_path)
    assert shown["broken"] == [] and shown["width"] <= 1280, shown
    assert [a for a in shown["alts"] if a.startswith("view ")] == ["view 1", "view 2", "view 3"]
    assert {"fused_scene", "support_graph", "f1", "views_map", "information_gain"} <= set(
        shown["alts"]
    )
    # the same page with a table too wide for the window, and an image that cannot load
    wide = tmp_path / "wide.html"
    wide.write_text(text + '<table><tr><td style="min-width:1600px">x</td></tr></table>'
                    '<img alt="missing" src="data:image/png;base64,AAAA">')  # fmt: skip
    bad = layout(wide, tmp_path)
    assert bad["width"] > 1280 and bad["broken"] == ["missing"], bad


def test_no_primitives_no_pictures_and_the_page_says_why_a_drawing_failed(tmp_path):
    e = {"roi": ROI, "final_primitives": [{"id": 1, "kind": "plane", "center": [0, 0, 0]}]}
    made = report.episode_figures(e, tmp_path, "")
    (scene, text), (graph, path) = made
    assert scene == "fused_scene" and text.startswith("fused_scene: not drawn (KeyError")
    assert graph == "support_graph" and isinstance(path, Path) and path.name == "support_graph.png"


def test_the_information_gain_plot_names_its_unit_and_its_seed_only_when_there_are_several(
    tmp_path, monkeypatch
):
    e = {"seed": 0, "views": [{"information_gain": 0.0, "realised_gain": 4e5},
                              {"information_gain": 1.2e4, "realised_gain": 9e3}]}  # fmt: skip
    seen: dict[str, str] = {}
    save = report._save

    def keep(fig, path):
        ax = fig.axes[0]
        seen.update(title=ax.get_title(), ylabel=ax.get_ylabel(), scale=ax.get_yscale())
        return save(fig, path)

    monkeypatch.setattr(report, "_save", keep)
    report.gain_plot({"utility": [e]}, tmp_path)
    assert seen == {"title": "information gain per view", "ylabel": "voxels", "scale": "symlog"}
    report.gain_plot({"utility": [e, e]}, tmp_path)
    assert seen["title"].endswith("(each strategy's first seed)")


def test_the_picture_keeps_what_meets_the_roi_and_labels_each_body_once():
    prims = primitives()
    floor = {"id": 9, "kind": "plane", "body": "floor", "center": [0.0, 0.0, 0.0],
             "extent": [6.0, 6.0, 0.01], "rotation": np.eye(3).tolist()}  # fmt: skip
    leg = {"id": 10, "kind": "cylinder", "body": "table", "center": [1.0, 0.5, 0.4],
           "extent": [0.04, 0.04, 0.7], "rotation": np.eye(3).tolist(), "inliers": 50}  # fmt: skip
    lost = {"id": 11, "kind": "box", "body": "", "center": [1.3, 0.0, 0.9],
            "extent": [0.1, 0.1, 0.1], "rotation": np.eye(3).tolist()}  # fmt: skip
    prims[0]["inliers"] = 5000
    kept = scene_figures.in_roi([*prims, floor, leg, lost], ROI)
    assert [p["id"] for p in kept] == [1, 2, 3, 10, 11]  # the floor's top is 0.75 m below
    assert [p["id"] for p in scene_figures.labels(kept)] == [1, 2, 3, 11]  # the leg: no label
