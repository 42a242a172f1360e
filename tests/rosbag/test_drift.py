"""``avs replay-dataset --drift MM,DEG``: the k-th frame's pose turned by k·DEG of yaw
about the vertical through the first camera and moved k·MM along +x (``dataset/drift.py``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from avs.cli import build_parser
from services.adapters.dataset.drift import Drift, drift_transform, drifted
from services.adapters.dataset.formats import Intrinsics, read
from services.adapters.dataset.frames import DatasetFrames
from services.common.poses import pose_difference


def _pose(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    a = math.radians(yaw_deg)
    T = np.eye(4)
    T[:3, :3] = [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
    T[:3, 3] = (x, y, z)
    return T


def test_drift_turns_about_the_pivot_and_shifts_along_x():
    d = Drift(0.5, 0.02)
    pivot = np.array([1.0, 2.0, 0.5])
    # frame 0: not moved
    np.testing.assert_allclose(drift_transform(0, d, pivot), np.eye(4), atol=1e-15)
    # frame 100: 2° of yaw, 50 mm along x. A camera at the pivot only moves 50 mm ...
    at_pivot = drifted(_pose(1.0, 2.0, 1.4, 30.0), 100, d, pivot)
    np.testing.assert_allclose(at_pivot[:3, 3], [1.05, 2.0, 1.4], atol=1e-12)
    moved, turned = pose_difference(_pose(1.0, 2.0, 1.4, 30.0), at_pivot)
    assert moved == pytest.approx(0.05, abs=1e-12) and turned == pytest.approx(2.0, abs=1e-9)
    np.testing.assert_allclose(at_pivot[:3, :3], _pose(0, 0, 0, 32.0)[:3, :3], atol=1e-12)
    # ... one 1 m east of it swings 2° around it: (cos 2° − 1 + 0.05, sin 2°) from where it was
    east = drifted(_pose(2.0, 2.0, 0.0), 100, d, pivot)
    np.testing.assert_allclose(east[:3, 3] - [2.0, 2.0, 0.0], [0.049391, 0.034899, 0.0], atol=1e-6)
    # the correction that undoes it is D_k⁻¹, whatever the camera
    for T in (_pose(0.3, -1, 1.2, 80), _pose(4, 4, 0.1, -10)):
        D = drift_transform(37, d, pivot)
        np.testing.assert_allclose(np.linalg.inv(D) @ drifted(T, 37, d, pivot), T, atol=1e-12)
        # and it grows linearly: 37 frames of yaw is 0.74°
        assert pose_difference(T, drifted(T, 37, d, pivot))[1] == pytest.approx(0.74, abs=1e-9)


def test_dataset_frames_carry_the_drift_of_their_play_order(tmp_path):
    """Every 2nd of 5 frames: the published k-th frame (seq k) has k frames of drift, about the
    first played camera; ``pose`` stays the reference."""
    (tmp_path / "rgb").mkdir()
    (tmp_path / "depth").mkdir()
    rgb, depth, truth = ["# rgb"], ["# depth"], ["# t tx ty tz qx qy qz qw"]
    for i in range(5):
        Image.new("RGB", (8, 6)).save(tmp_path / "rgb" / f"{i}.png")
        Image.fromarray(np.full((6, 8), 5000, np.uint16)).save(tmp_path / "depth" / f"{i}.png")
        rgb.append(f"{i * 0.1:.2f} rgb/{i}.png")
        depth.append(f"{i * 0.1:.2f} depth/{i}.png")
        truth.append(f"{i * 0.1:.2f} {0.5 + i * 0.1} 1 1.2 0 0 0 1")
    for name, lines in (("rgb", rgb), ("depth", depth), ("groundtruth", truth)):
        (tmp_path / f"{name}.txt").write_text("\n".join(lines) + "\n")
    rec = read(tmp_path, intrinsics=Intrinsics(0, 0, 5.0, 5.0, 4.0, 3.0))
    frames = DatasetFrames(rec, every=2, drift=Drift(10.0, 1.0))
    got = list(frames)
    assert [f.seq for f in got] == [0, 1, 2]
    np.testing.assert_allclose(got[0].T_world_camera, frames.pose(0))
    # seq 2 is dataset frame 4, at x = 0.9: 2° about the first camera (x = 0.5) and 20 mm on x
    a = math.radians(2.0)
    want = [0.5 + 0.4 * math.cos(a) + 0.02, 1 + 0.4 * math.sin(a), 1.2]
    np.testing.assert_allclose(got[2].T_world_camera[:3, 3], want, atol=1e-6)
    assert pose_difference(frames.pose(4), got[2].T_world_camera)[1] == pytest.approx(2.0)


def test_the_command_takes_the_drift_as_mm_and_degrees(capsys):
    parser = build_parser()
    args = parser.parse_args(["replay-dataset", "x", "--drift", "0.5,0.02"])
    assert args.drift == Drift(0.5, 0.02)
    assert parser.parse_args(["replay-dataset", "x"]).drift is None
    with pytest.raises(SystemExit):
        parser.parse_args(["replay-dataset", "x", "--drift", "0.5"])
    assert "--drift wants MM,DEG" in capsys.readouterr().err
