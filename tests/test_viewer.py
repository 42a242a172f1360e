"""``avs view``: what it draws (the pure core, read back from a recording with rerun's own
reader), an exploration episode recorded headless (``avs explore --save-view``) with every
entity path checked for data of the right shapes, and ``avs view --web`` loaded by a headless
Chromium while the gaze service publishes its ego-sphere."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import pyarrow as pa
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from avs.viewer import KINDS, TIMELINE, SceneLogger, back_project, log_entities, occupied_blocks
from schemas import (
    BasePose,
    CameraIntrinsics,
    Keys,
    OccupancySlice,
    RgbdFrame,
    SceneModel,
    SupportEdge,
)
from tests.conftest import ROOT, avs_env, free_port, liveliness_tokens, wait_for
from tests.scene_memory.builders import box, camera_above, cylinder, observation, plane

Rows = dict[str, list[dict[str, Any]]]


def read_recording(path: Path) -> Rows:
    """Every entity's rows (component → value, the timeline as int ns), in time order, as
    rerun's reader returns them."""
    rows: Rows = defaultdict(list)
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        columns = {}
        for name, column in zip(batch.schema.names, batch.columns, strict=True):
            if pa.types.is_timestamp(column.type):
                column = column.cast(pa.int64())
            columns[name] = column.to_pylist()
        for i in range(batch.num_rows):
            rows[chunk.entity_path].append({k: v[i] for k, v in columns.items()})
    for entity in rows.values():
        entity.sort(key=lambda r: r.get(TIMELINE) or 0)
    return dict(rows)


def last(rows: Rows, entity: str, component: str) -> Any:
    """The newest logged value of ``component`` at ``entity``."""
    values = [r[component] for r in rows.get(entity, []) if r.get(component) is not None]
    assert values, f"{entity} holds no {component} (entities: {sorted(rows)})"
    return values[-1]


def record(tmp_path: Path, messages: list) -> Rows:
    """Draw ``messages`` with a SceneLogger into an .rrd file and read it back."""
    path = tmp_path / "unit.rrd"
    recording = rr.RecordingStream("avs-test")
    recording.save(str(path))
    logger = SceneLogger()
    log_entities(recording, logger.setup(), 1.0)
    for i, m in enumerate(messages):
        log_entities(recording, logger.entities(m), 2.0 + i)
    recording.flush()
    recording.disconnect()
    return read_recording(path)


def test_primitives_by_kind_support_graph_and_unstable_ones_are_drawn(tmp_path):
    table = plane(0, (0.5, 1.5), (-0.5, 0.5), 0.75)
    cup = cylinder(1, (1.0, 0.1, 0.75), 0.04, 0.12, 0.0)
    books = box(2, (0.8, -0.2, 0.8), (0.2, 0.15, 0.1))
    lid = box(3, (0.8, -0.2, 0.9), (0.1, 0.1, 0.02))
    obs = observation(1, [table, cup, books, lid], support=[(0, 1), (0, 2), (2, 3)])
    obs = obs.model_copy(update={"root_id": 0, "unstable_ids": [3]})
    fused = SceneModel(
        seq=1, stamp=1.0, model_version=1, n_views=1, fusion="sg",
        primitives=obs.primitives, root_id=0, unstable_ids=[3], unresolved_ids=[1],
        support_edges=[SupportEdge(supporter=0, supported=1, occ=3),
                       SupportEdge(supporter=0, supported=2, occ=1)],
    )  # fmt: skip
    rows = record(tmp_path, [obs, fused])

    assert last(rows, "/world", "ViewCoordinates:xyz") is not None
    boxes = "/world/observation/primitives/box"
    assert last(rows, boxes, "Boxes3D:labels") == ["box 2", "box 3"]
    assert np.allclose(last(rows, boxes, "Boxes3D:centers"), [[0.8, -0.2, 0.8], [0.8, -0.2, 0.9]])
    assert np.allclose(last(rows, boxes, "Boxes3D:half_sizes")[0], [0.1, 0.075, 0.05])
    cylinders = "/world/observation/primitives/cylinder"
    assert last(rows, cylinders, "Cylinders3D:labels") == ["cylinder 1"]
    assert np.allclose(last(rows, cylinders, "Cylinders3D:radii"), [0.04])
    assert np.allclose(last(rows, cylinders, "Cylinders3D:lengths"), [0.12])
    assert last(rows, "/world/observation/primitives/plane", "Boxes3D:labels") == ["plane 0"]
    # a kind without primitives is logged empty: nothing stale stays on screen
    assert last(rows, "/world/observation/primitives/sphere", "Ellipsoids3D:centers") == []
    shapes = {"plane": "Boxes3D", "box": "Boxes3D", "cylinder": "Cylinders3D",
              "sphere": "Ellipsoids3D"}  # fmt: skip
    total = sum(
        len(last(rows, f"/world/observation/primitives/{k}", f"{a}:centers"))
        for k, a in shapes.items()
    )
    assert total == len(obs.primitives) == 4
    # support graph: supporter centre → supported centre, red into the unstable lid
    origins = np.array(last(rows, "/world/observation/support_graph", "Arrows3D:origins"))
    vectors = np.array(last(rows, "/world/observation/support_graph", "Arrows3D:vectors"))
    assert origins.shape == vectors.shape == (3, 3)
    assert np.allclose(origins[2] + vectors[2], [0.8, -0.2, 0.9], atol=1e-6)
    colours = last(rows, "/world/observation/support_graph", "Arrows3D:colors")
    assert colours[0] == colours[1] != colours[2]
    assert last(rows, "/world/observation/unstable", "Points3D:labels") == ["unstable 3"]
    assert np.allclose(last(rows, "/world/observation/unstable", "Points3D:positions"),
                       [[0.8, -0.2, 0.9]])  # fmt: skip
    # the fused model: its own entities, occ(e) on the arrows
    assert last(rows, "/world/scene/support_graph", "Arrows3D:labels") == ["occ 3", "occ 1"]
    assert len(last(rows, "/world/scene/primitives/box", "Boxes3D:centers")) == 2
    # ... and the cup, whose support no view saw, amber apart from the unstable lid
    assert last(rows, "/world/scene/unresolved", "Points3D:labels") == ["unresolved 1"]
    assert last(rows, "/world/scene/unstable", "Points3D:labels") == ["unstable 3"]
    assert set(KINDS) == {"plane", "box", "cylinder", "sphere"}


def test_a_frame_is_a_camera_with_images_and_its_cloud_in_the_world(tmp_path):
    K = CameraIntrinsics(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    depth = np.full((48, 64), 1.5, np.float32)
    depth[:8] = 0.0  # no return in the top rows
    rgb = np.zeros((48, 64, 3), np.uint8)
    rgb[..., 0] = 200
    T = camera_above(1.0, 0.0, 2.5)  # looking down: depth 1.5 m is the plane z = 1.0
    frame = RgbdFrame(seq=1, stamp=0.5, camera="head_rgbd", intrinsics=K, rgb=rgb, depth=depth,
                      T_world_camera=T, depth_max=3.0)  # fmt: skip
    rows = record(tmp_path, [frame])

    fmt = last(rows, "/world/cameras/head_rgbd/rgb", "Image:format")[0]
    assert (fmt["height"], fmt["width"]) == (48, 64)
    assert len(last(rows, "/world/cameras/head_rgbd/rgb", "Image:buffer")[0]) == 48 * 64 * 3
    fmt = last(rows, "/world/cameras/head_rgbd/depth", "DepthImage:format")[0]
    assert (fmt["height"], fmt["width"]) == (48, 64)
    assert len(last(rows, "/world/cameras/head_rgbd/depth", "DepthImage:buffer")[0]) == 48 * 64 * 4
    assert np.allclose(last(rows, "/world/cameras/head_rgbd", "Transform3D:translation"),
                       [1.0, 0.0, 2.5])  # fmt: skip
    assert last(rows, "/world/cameras/head_rgbd", "Pinhole:resolution") == [[64.0, 48.0]]
    points = np.array(last(rows, "/world/cloud/head_rgbd", "Points3D:positions"))
    assert points.shape == ((48 - 8) // 4 * (64 // 4), 3)  # every 4th pixel with a return
    assert np.allclose(points[:, 2], 1.0, atol=1e-5)
    # the image's top rows (no return) are the far +y side: the camera's y axis points to -y
    assert points[:, 1].max() < 40 / 50 * 1.5 / 2 + 1e-3
    assert len(last(rows, "/world/cloud/head_rgbd", "Points3D:colors")) == len(points)


def test_back_projection_and_the_pooled_map():
    K = CameraIntrinsics(width=4, height=2, fx=1.0, fy=1.0, cx=1.5, cy=0.5)
    depth = np.array([[1.0, 2.0, 0.0, 4.0], [1.0, 1.0, 1.0, 9.0]], np.float32)
    points, colours = back_project(depth, K, np.eye(4), stride=1, depth_max=5.0)
    assert colours is None
    assert points.shape == (6, 3)  # the 0 and the 9 m (beyond depth_max) are left out
    assert np.allclose(points[0], [-1.5 * 1.0, -0.5 * 1.0, 1.0])
    states = np.zeros((10, 10, 10), np.uint8)
    states[0, 0, 0] = states[9, 9, 9] = states[1, 1, 1] = OccupancySlice.OCCUPIED
    states[5, 5, 5] = OccupancySlice.FREE
    centres, side = occupied_blocks(states, np.array([0.0, 0.0, 0.0]), 0.01, 0.04)
    assert side == pytest.approx(0.04)
    assert len(centres) == 2  # (0,0,0) and (1,1,1) share a 4-voxel cube
    assert np.allclose(sorted(centres[:, 0]), [0.02, 0.10])
    centres, side = occupied_blocks(states, np.zeros(3), 0.01, 0.01, max_blocks=2)
    assert len(centres) <= 2 and side > 0.01  # coarser until few enough


def test_the_platform_path_grows_by_steps(tmp_path):
    poses = [BasePose(seq=i, stamp=i * 0.01, x=0.001 * i, y=0.0, yaw=0.0) for i in range(101)]
    rows = record(tmp_path, poses)
    strip = np.array(last(rows, "/world/path", "LineStrips3D:strips")[0])
    steps = np.diff(strip[:, 0])
    assert strip.shape[1] == 3 and 5 <= len(strip) <= 6  # a point per 2 cm of the 10 cm driven
    assert np.all((steps > 0.0199) & (steps < 0.0211)) and np.allclose(strip[0], [0, 0, 0.01])
    assert 0.08 <= strip[-1, 0] <= 0.1
    assert np.allclose(last(rows, "/world/platform", "Transform3D:translation"), [0.1, 0, 0])


def view_env() -> dict[str, str]:
    env = dict(os.environ, MUJOCO_GL="egl")
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.timeout(300)
def test_explore_save_view_records_every_entity_with_its_shape(tmp_path):
    out, rrd = tmp_path / "runs" / "explore", tmp_path / "run.rrd"  # explore's default --out
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "avs.cli", "--log-level", "WARNING", "explore",
         "--scene", "tabletop_occluded", "--save-view", "run.rrd", "--views", "2"],
        env=view_env(), cwd=tmp_path, capture_output=True, text=True, timeout=280,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    print(f"episode with the viewer: {time.monotonic() - t0:.1f} s, {rrd.stat().st_size} B")
    rerun_cli = Path(sys.executable).with_name("rerun")
    verified = subprocess.run([str(rerun_cli), "rrd", "verify", str(rrd)], capture_output=True,
                              text=True, timeout=60)  # fmt: skip
    assert verified.returncode == 0, verified.stderr
    result = json.loads((out / "metrics.json").read_text())
    rows = read_recording(rrd)

    # every drawn entity is on the one timeline
    for entity, entity_rows in rows.items():
        if entity not in ("/__properties", "/world"):
            assert all(r.get(TIMELINE) for r in entity_rows), entity
    camera = "/world/cameras/head_rgbd"
    assert len(rows[f"{camera}/rgb"]) == 2  # one frame per view
    for image, component, depth in (("rgb", "Image", 3), ("depth", "DepthImage", 4)):
        fmt = last(rows, f"{camera}/{image}", f"{component}:format")[0]
        assert (fmt["height"], fmt["width"]) == (480, 640)
        assert len(last(rows, f"{camera}/{image}", f"{component}:buffer")[0]) == 480 * 640 * depth
    assert np.array(last(rows, camera, "Transform3D:translation")).shape == (1, 3)
    assert last(rows, camera, "Pinhole:resolution") == [[640.0, 480.0]]
    cloud = np.array(last(rows, "/world/cloud/head_rgbd", "Points3D:positions"))
    assert cloud.ndim == 2 and cloud.shape[1] == 3 and len(cloud) > 5000
    lo, hi = np.array(result["roi"])
    roi_centre = last(rows, "/world/map/roi", "Boxes3D:centers")
    assert np.allclose(roi_centre, [(lo + hi) / 2], atol=1e-6)
    # the perceived and the fused primitives: shapes per kind, as many as the model holds
    component = {"plane": "Boxes3D", "box": "Boxes3D", "cylinder": "Cylinders3D",
                 "sphere": "Ellipsoids3D"}  # fmt: skip
    for prefix in ("observation", "scene"):
        labels = []
        for kind, archetype in component.items():
            entity = f"/world/{prefix}/primitives/{kind}"
            centres = last(rows, entity, f"{archetype}:centers")
            assert np.array(centres).reshape(-1, 3).shape == (len(centres), 3)
            kind_labels = last(rows, entity, f"{archetype}:labels") if centres else []
            assert len(kind_labels) == len(centres)
            labels += kind_labels
        assert labels, prefix
        if prefix == "scene":  # the last fused model is the episode's final one
            final = {f"{p['kind']} {p['id']}" for p in result["final_primitives"]}
            assert set(labels) == final
    arrows = last(rows, "/world/scene/support_graph", "Arrows3D:origins")
    assert len(arrows) == len(result["final_support_edges"]) > 0
    assert len(last(rows, "/world/observation/support_graph", "Arrows3D:vectors")) > 0
    assert "/world/scene/unstable" in rows and "/world/observation/unstable" in rows
    occupied = np.array(last(rows, "/world/map/occupied", "Boxes3D:centers"))
    assert occupied.shape[1] == 3 and len(occupied) > 100
    assert np.allclose(last(rows, "/world/map/occupied", "Boxes3D:half_sizes")[0], 0.02)
    origins = np.array(last(rows, "/world/nbv/candidates", "Arrows3D:origins"))
    colours = last(rows, "/world/nbv/candidates", "Arrows3D:colors")
    assert origins.shape[1] == 3 and len(origins) == len(colours) > 10
    assert len(set(colours)) > 3  # coloured by utility
    assert last(rows, "/world/nbv/next_view", "Pinhole:resolution") == [[640.0, 480.0]]
    assert len(last(rows, "/world/nbv/target", "Points3D:positions")) == 1
    assert len(last(rows, "/world/gaze/target", "Points3D:positions")) == 1
    path = np.array(last(rows, "/world/path", "LineStrips3D:strips")[0])
    trajectory = result["views"][-1]["trajectory"]
    assert path.shape[1] == 3 and len(path) >= 2
    assert np.allclose(path[-1, :2], trajectory[-1], atol=0.05)  # where the platform ended
    assert len(rows["/world/platform"]) > 2


def chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def net_log_responses(path: Path) -> dict[str, str]:
    """URL → the status line of its response, from Chromium's ``--log-net-log``."""
    log = json.loads(path.read_text())
    names = {v: k for k, v in log["constants"]["logEventTypes"].items()}
    urls, status = {}, {}
    for e in log["events"]:
        params, source = e.get("params", {}), e["source"]["id"]
        if names[e["type"]] == "URL_REQUEST_START_JOB" and "url" in params:
            urls[source] = params["url"]
        elif names[e["type"]] == "HTTP_TRANSACTION_READ_RESPONSE_HEADERS" and source in urls:
            status[urls[source]] = params["headers"][0]
    return status


@pytest.mark.timeout(180)
def test_view_web_is_loaded_by_chromium_and_records_the_ego_sphere(router, client, procs,
                                                                    tmp_path):  # fmt: skip
    browser = chromium()
    if browser is None:
        if os.environ.get("AVS_REQUIRE_CHROMIUM"):
            pytest.fail("AVS_REQUIRE_CHROMIUM is set but there is no chromium on PATH")
        pytest.skip("no chromium: apt-get install chromium (scripts/test does, as root)")
    keys = Keys("armar6")
    procs.python(["-m", "services.gaze", "--instance", "gaze-view"], env=avs_env(router))
    web_port, grpc_port, rrd = free_port(), free_port(), tmp_path / "live.rrd"
    view = procs.python(
        ["-m", "avs.cli", "view", "--web", "--web-port", str(web_port), "--grpc-port",
         str(grpc_port), "--save", str(rrd), "--connect", router, "--instance", "web"],
        env=view_env(), stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    wanted = {keys.alive("gaze", "gaze-view"), keys.alive("view", "web")}
    wait_for(lambda: wanted <= liveliness_tokens(client, keys.alive()), 90, "gaze and view")
    line = view.stdout.readline()
    while "web viewer:" not in line:
        assert line, "avs view ended without printing the web viewer's address"
        line = view.stdout.readline()
    url = line.split("web viewer:", 1)[1].strip()
    assert url.startswith(f"http://localhost:{web_port}/")

    def listening() -> set[tuple[str, int]]:
        return {
            (c.laddr.ip, c.laddr.port)
            for c in psutil.net_connections(kind="inet")
            if c.status == psutil.CONN_LISTEN and c.laddr.port in (web_port, grpc_port)
        }

    # the page and the data proxy listen on this machine only (--bind, default 127.0.0.1)
    bound = listening()
    assert bound == {("127.0.0.1", web_port), ("127.0.0.1", grpc_port)}, bound
    with urllib.request.urlopen(url, timeout=10) as page:
        assert page.status == 200
        assert b"re_viewer" in page.read()

    net_log, shot = tmp_path / "net.json", tmp_path / "viewer.png"
    subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
         f"--user-data-dir={tmp_path / 'chromium'}", f"--log-net-log={net_log}",
         "--virtual-time-budget=10000", "--window-size=1280,800", f"--screenshot={shot}", url],
        capture_output=True, timeout=90, check=True,
    )  # fmt: skip
    responses = net_log_responses(net_log)
    assert responses.get(url, "").endswith("200 OK"), responses
    wasm = [u for u in responses if u.endswith(".wasm")]
    assert wasm and all(responses[u].endswith("200 OK") for u in wasm), responses

    # the gaze service's ego-sphere (2 Hz): wait for two snapshots' worth, then stop the viewer
    time.sleep(1.5)
    view.send_signal(signal.SIGINT)
    view.wait(60)
    assert view.returncode == 0
    # and the rerun server it started ended with it (the binary under the venv's wrapper too)
    wait_for(lambda: not listening(), 10, "the rerun server's ports closed")
    rows = read_recording(rrd)
    points = np.array(last(rows, "/world/platform/ego_sphere", "Points3D:positions"))
    colours = last(rows, "/world/platform/ego_sphere", "Points3D:colors")
    assert points.shape == (40_000 // 20, 3) and len(colours) == len(points)  # every 20th
    radius = np.linalg.norm(points - [0, 0, 1.6], axis=1)
    assert np.allclose(radius, 0.35, atol=1e-3)  # unit directions on the drawn sphere


def test_no_flag_is_taken_for_an_abbreviation_and_view_needs_somewhere_to_show(tmp_path):
    from avs.cli import build_parser

    parser = build_parser()
    args = parser.parse_args(["explore", "--out", "x", "--views", "3", "--save-view", "r.rrd"])
    assert (args.views, args.save_view, args.viewer) == (3, Path("r.rrd"), False)
    with pytest.raises(SystemExit) as exit_:
        parser.parse_args(["explore", "--out", "x", "--view", "3"])  # not --views, not --viewer
    assert exit_.value.code == 2
    env = {k: v for k, v in view_env().items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    out = subprocess.run(
        [sys.executable, "-m", "avs.cli", "view", "--connect", "tcp/127.0.0.1:9"],
        env=env, cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode != 0 and "--web" in out.stderr and "--save" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
