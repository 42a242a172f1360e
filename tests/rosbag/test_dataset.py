"""``avs replay-dataset``: recorded RGB-D datasets on disk (TUM, 7-Scenes, a folder) read as
RgbdFrames, gravity found from their level planes, and played over Zenoh.

The real recordings (``../shared/data/real``: a Kinect kitchen from 7-Scenes, a Fetch robot's
head camera) are read where they are, never copied here (7-Scenes' licence); without them the
tests that need them are skipped, saying where the data comes from."""

from __future__ import annotations

import subprocess
import sys
import threading

import numpy as np
import pytest
import zenoh
from PIL import Image

from schemas import Keys, RgbdFrame, decode
from services.adapters.dataset.formats import DatasetError, detect, read
from services.adapters.dataset.frames import DatasetFrames
from services.adapters.dataset.gravity import back_project, level_frame
from tests.conftest import ROOT, avs_env, free_port, session_config, wait_for
from tests.real import REAL, needs_real


def _write_tum(root, stamps_rgb, stamps_depth, size=(64, 48), value=5000):
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    lines_rgb, lines_depth = ["# colour"], ["# depth"]
    for i, t in enumerate(stamps_rgb):
        Image.new("RGB", size, (10 * i, 0, 0)).save(root / "rgb" / f"{i}.png")
        lines_rgb.append(f"{t:.6f} rgb/{i}.png")
    for i, t in enumerate(stamps_depth):
        Image.fromarray(np.full(size[::-1], value + i, np.uint16)).save(root / "depth" / f"{i}.png")
        lines_depth.append(f"{t:.6f} depth/{i}.png")
    (root / "rgb.txt").write_text("\n".join(lines_rgb) + "\n")
    (root / "depth.txt").write_text("\n".join(lines_depth) + "\n")


def test_a_tum_folder_pairs_colour_and_depth_by_the_nearest_stamp(tmp_path):
    _write_tum(tmp_path, [1.00, 1.10, 1.20], [1.005, 1.14, 1.195])
    (tmp_path / "groundtruth.txt").write_text(
        "# t tx ty tz qx qy qz qw\n1.0 1 2 3 0 0 0 1\n1.2 1 2 4 0 0 0.7071068 0.7071068\n"
    )
    assert detect(tmp_path) == "tum"
    with pytest.raises(DatasetError, match="--intrinsics"):
        read(tmp_path)
    from services.adapters.dataset.formats import Intrinsics

    rec = read(tmp_path, intrinsics=Intrinsics(0, 0, 50.0, 50.0, 32.0, 24.0))
    # 1.10 has no depth within 20 ms (1.14 is 40 ms away): skipped, and said so
    assert rec.stamps == [1.00, 1.20] and rec.skipped == {"no depth within max_dt": 1}
    assert [p.name for p in rec.depth] == ["0.png", "2.png"]
    frames = list(DatasetFrames(rec))
    assert [f.seq for f in frames] == [0, 1] and frames[1].stamp == pytest.approx(0.2)
    assert frames[0].depth[0, 0] == pytest.approx(1.0)  # 5000 / 5000
    assert frames[1].depth[0, 0] == pytest.approx(5002 / 5000)
    np.testing.assert_allclose(frames[0].T_world_camera[:3, 3], [1, 2, 3])
    # the second pose turns 90° about z (the nearest groundtruth stamp)
    np.testing.assert_allclose(frames[1].T_world_camera[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-6)


def test_bad_datasets_name_their_problem(tmp_path):
    with pytest.raises(DatasetError, match="not a folder"):
        detect(tmp_path / "nope")
    with pytest.raises(DatasetError, match="no dataset layout found"):
        detect(tmp_path)
    _write_tum(tmp_path / "t", [1.0], [1.0])
    (tmp_path / "t" / "intrinsics.txt").write_text("64 48 50 50 32\n")
    with pytest.raises(DatasetError, match=r"intrinsics\.txt: expected 'w h fx fy cx cy"):
        read(tmp_path / "t")
    (tmp_path / "t" / "intrinsics.txt").write_text("64 48 50 50 32 24 5000\n")
    Image.new("RGB", (32, 24)).save(tmp_path / "t" / "rgb" / "0.png")  # half the depth's size
    with pytest.raises(DatasetError, match=r"0.png is 32×24, its depth 64×48.*--no-colour"):
        list(DatasetFrames(read(tmp_path / "t")))
    assert len(list(DatasetFrames(read(tmp_path / "t"), colour=False))) == 1
    seven = tmp_path / "s"
    seven.mkdir()
    Image.fromarray(np.zeros((4, 4), np.uint16)).save(seven / "frame-000000.depth.png")
    with pytest.raises(DatasetError, match="has no colour image"):
        read(seven)
    Image.new("RGB", (4, 4)).save(seven / "frame-000000.color.jpg")
    (seven / "frame-000000.pose.txt").write_text("2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    with pytest.raises(DatasetError, match="is no rotation"):
        read(seven, intrinsics=None)


@needs_real
def test_the_kinect_kitchen_is_read_and_turned_upright():
    """7-Scenes redkitchen: its world is the first camera's (z not up). After ``--up auto``
    the floor's points lie at z = 0 and the table top is level, 0.6-0.8 m above it."""
    rec = read(REAL / "redkitchen-a")
    assert rec.format == "7scenes" and len(rec) == 100 and rec.poses is not None
    assert (rec.intrinsics.fx, rec.intrinsics.cx) == (585.0, 320.0)
    frames = DatasetFrames(rec, every=5)
    f = frames.frame(0, 0)
    assert f.depth.shape == (480, 640) and f.rgb.shape == (480, 640, 3)
    assert 0.05 < (f.depth == 0).mean() < 0.6  # holes (65535 and 0) are 0, not 65.5 m
    assert 0.3 < np.median(f.depth[f.depth > 0]) < 4.0
    up = level_frame(frames)
    assert abs(up.up[2]) < 0.9  # the dataset's z is not up: the world is turned
    heights = [h for h, _ in up.planes]
    assert heights[0] == 0.0 and any(0.6 < h < 0.8 for h in heights), up.planes
    frames.T_up = up.T_up
    k = f.intrinsics
    points = np.concatenate([
        back_project(g.depth, k.fx, k.fy, k.cx, k.cy, g.T_world_camera)
        for g in (frames.frame(i, 0) for i in frames.indices()[::4])
    ])  # fmt: skip
    z = points[:, 2]
    floor = z[np.abs(z) < 0.05]
    assert len(floor) > 0.03 * len(z) and abs(np.median(floor)) < 0.01
    assert np.percentile(z, 1) > -0.1  # nothing far below the floor


@needs_real
def test_the_fetch_head_camera_keeps_the_robots_frame():
    """fetch-table: TUM-like, poses in the robot's base_link (z up, the floor at 0), the
    intrinsics in its intrinsics.txt. ``--up auto`` finds z up already and keeps the frame;
    the table top comes out level at 0.72 m (the folder's README: 0.719 with these
    intrinsics)."""
    rec = read(REAL / "fetch-table")
    assert rec.format == "tum" and len(rec) == 30 and rec.depth_scale == pytest.approx(1 / 5000)
    frames = DatasetFrames(rec)
    up = level_frame(frames)
    np.testing.assert_allclose(up.T_up, np.eye(4))
    assert "z is up already" in up.detail
    assert any(abs(h - 0.719) < 0.02 for h, _ in up.planes), up.planes


@needs_real
def test_replay_dataset_plays_the_frames_over_zenoh(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    keys = Keys()
    got: list[RgbdFrame] = []
    lock = threading.Lock()

    def keep(sample) -> None:
        with lock:
            got.append(decode(sample.payload.to_bytes(), RgbdFrame))

    with zenoh.open(session_config("router", listen=[endpoint])) as router:
        router.declare_subscriber(keys.rgbd("head_rgbd"), keep)
        done = subprocess.run(
            [sys.executable, "-m", "avs.cli", "replay-dataset", str(REAL / "redkitchen-a"),
             "--every", "10", "--limit", "4", "--rate", "0", "--up-file", str(tmp_path / "up.json"),
             "--connect", endpoint],
            cwd=ROOT, env=avs_env(endpoint), capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert done.returncode == 0, done.stderr
        assert "up: " in done.stderr and "the floor" in done.stderr
        wait_for(lambda: len(got) >= 4, 20, "4 frames")
    assert [f.seq for f in got] == [0, 1, 2, 3]
    assert [round(f.stamp, 3) for f in got] == [0.0, 1.667, 3.333, 5.0]  # every 10th of 5th
    import json

    T_up = np.array(json.loads((tmp_path / "up.json").read_text())["T_up"])
    rec = read(REAL / "redkitchen-a")
    np.testing.assert_allclose(got[1].T_world_camera, T_up @ rec.poses[10], atol=1e-5)
    bad = subprocess.run(
        [sys.executable, "-m", "avs.cli", "replay-dataset", str(tmp_path), "--connect", endpoint],
        cwd=ROOT, env=avs_env(endpoint), capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert bad.returncode != 0 and "avs replay-dataset: " in bad.stderr
    assert "no dataset layout found" in bad.stderr
