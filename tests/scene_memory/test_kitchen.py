"""`avs fuse` on the kitchen, an orbit of 20 views around the counter with the robot's sensor
models (depth noise, odometry drifting along the drive) and view registration: the camera poses
stay within a centimetre of the truth, the fused model explains the roi's bodies (thesis Fig.
3.10) and settles (fewer modified primitives per view in the second half, Fig. 3.11);
unregistered, the drift shows in the indices."""

from __future__ import annotations

import json
import subprocess
import sys
from itertools import pairwise

from tests.conftest import ROOT


def test_kitchen_orbit_of_20_views(tmp_path):
    out = tmp_path / "fuse"
    run = subprocess.run(
        [sys.executable, "-m", "avs.cli", "fuse", "--scene", "kitchen", "--path", "orbit",
         "--views", "20", "--fusion", "sg", "--voxel", "0.02", "--out", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    assert " 20/20 " in run.stderr  # progress shown
    views = json.loads((out / "metrics.json").read_text())["views"]
    assert len(views) == 20
    keys = {"view", "inlier_index", "overlapping_index", "added", "modified", "removed",
            "unknown_voxels", "integrate_ms", "fuse_ms", "pose_error_m", "pose_error_deg",
            "registration_ms"}  # fmt: skip
    assert keys <= set(views[0])
    last = views[-1]
    # issue 15's bounds; measured 2.9 mm, 0.08°, InlierIndex 0.94, OverlappingIndex 0.82 (the
    # simulator's truth, without depth noise or drift: 0.97 and 0.84)
    assert last["pose_error_m"] <= 0.01 and last["pose_error_deg"] <= 0.5, last
    assert last["inlier_index"] >= 0.9 and last["overlapping_index"] >= 0.8, last
    modified = [v["modified"] for v in views]
    assert sum(modified[10:]) < sum(modified[:10]), modified
    unknown = [v["unknown_voxels"] for v in views]
    assert all(b <= a for a, b in pairwise(unknown))  # it only ever learns
    assert unknown[-1] < 0.75 * unknown[0]
    assert (out / "fusion.png").stat().st_size > 10_000


def fuse(tmp_path, *args: str) -> list[dict]:
    out = tmp_path / "-".join(args)
    run = subprocess.run(
        [sys.executable, "-m", "avs.cli", "fuse", "--scene", "kitchen", "--path", "orbit",
         "--views", "8", "--voxel", "0.02", "--out", str(out), *args],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-2000:]
    return json.loads((out / "metrics.json").read_text())["views"]


def test_registration_holds_the_kitchen_together_under_odometry_drift(tmp_path):
    """Eight orbit views with the odometry drifting (1.5 % of the ~6 m driven, 1° a turn):
    registered, every view's camera pose stays within 1 cm and 0.5° of the truth (4.7 mm and
    0.18° measured); unregistered, the last is 35 mm off and the model's overlap with the
    truth falls (OverlappingIndex 0.80 → 0.57 measured)."""
    registered = fuse(tmp_path)
    unregistered = fuse(tmp_path, "--registration", "off")
    worst = max(v["pose_error_m"] for v in registered)
    assert worst <= 0.01 and max(v["pose_error_deg"] for v in registered) <= 0.5, registered
    assert all(v["registration_ms"] > 0 for v in registered[1:])
    drifted = unregistered[-1]["pose_error_m"]
    assert drifted > 0.02 and drifted > 4 * worst, (drifted, worst)
    last, bad = registered[-1], unregistered[-1]
    assert last["inlier_index"] >= 0.9 and last["overlapping_index"] >= 0.78, last
    assert bad["overlapping_index"] < last["overlapping_index"] - 0.1, (bad, last)
