"""`avs fuse` on the kitchen, an orbit of 20 views around the counter: the fused model explains
the roi's bodies (InlierIndex ≥ 0.9, OverlappingIndex ≥ 0.8, thesis Fig. 3.10) and settles
(fewer modified primitives per view in the second half, Fig. 3.11)."""

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
    assert "view 20/20" in run.stderr  # progress shown
    views = json.loads((out / "metrics.json").read_text())["views"]
    assert len(views) == 20
    keys = {"view", "inlier_index", "overlapping_index", "added", "modified", "removed",
            "unknown_voxels", "integrate_ms", "fuse_ms"}  # fmt: skip
    assert keys <= set(views[0])
    last = views[-1]
    assert last["inlier_index"] >= 0.9 and last["overlapping_index"] >= 0.8, last
    modified = [v["modified"] for v in views]
    assert sum(modified[10:]) < sum(modified[:10]), modified
    unknown = [v["unknown_voxels"] for v in views]
    assert all(b <= a for a, b in pairwise(unknown))  # it only ever learns
    assert unknown[-1] < 0.75 * unknown[0]
    assert (out / "fusion.png").stat().st_size > 10_000
