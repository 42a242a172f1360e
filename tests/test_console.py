"""The main job (``scripts/run``: an exploration episode, every service a process) and its
console: a few lines (progress, summary, where the outputs are), every service's log in
OUT/logs, nothing else."""

from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest

from avs.console import Follow

ROOT = Path(__file__).resolve().parent.parent
SERVICES = ("sim", "perception", "scene_memory", "nbv")


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_main_job_prints_a_few_lines_and_logs_each_service(tmp_path):
    out = tmp_path / "explore"
    run = subprocess.run(
        ["bash", str(ROOT / "scripts" / "run"), "--out", str(out)],
        capture_output=True, text=True, timeout=580, env=dict(os.environ),
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    console = run.stdout + run.stderr
    lines = console.splitlines()
    assert 0 < len(lines) <= 15, console
    assert "leaked" not in console and "Traceback" not in console, console
    assert "terminated by" in console and str(out / "logs") in console
    for service in SERVICES:
        log = (out / "logs" / f"{service}.log").read_text()
        assert f"{service}[{service}-0] node up" in log, log[-2000:]
        assert "leaked" not in log and "Traceback" not in log, log[-3000:]
        assert "settings=" not in log, "the settings belong at DEBUG, not on an INFO line"
    assert "started sim-0" in (out / "logs" / "avs.log").read_text()
    metrics = json.loads((out / "metrics.json").read_text())
    views = len(metrics["views"])
    assert f"tabletop_occluded: {views} views, terminated by quality" in run.stdout
    assert f" {views}/{views} terminated by quality" in run.stderr  # the progress bar's end
    assert metrics["views"][-1]["support_f1"] >= 0.9
    for name in ("f1.png", "unknown_voxels.png", "path_cost.png", "views_map.png", "report.html"):
        assert (out / name).stat().st_size > 1000, name


def test_follow_prints_whole_new_lines_of_each_log(tmp_path, capsys):
    (tmp_path / "a" / "logs").mkdir(parents=True)
    first = tmp_path / "sim.log"
    nested = tmp_path / "a" / "logs" / "nbv.log"
    first.write_text("one\ntwo\nhalf")
    nested.write_text("x\n")
    (tmp_path / "avs.log").write_text("our own line\n")
    follow = Follow(tmp_path, every=0.05).start()
    time.sleep(0.3)
    with first.open("a") as f:
        f.write(" done\nthree\n")
    follow.stop()
    printed = capsys.readouterr().err.splitlines()
    assert printed.count("sim| one") == 1 and printed.count("sim| two") == 1
    assert "sim| half done" in printed and "sim| three" in printed
    assert "a/nbv| x" in printed
    assert not any("our own line" in p for p in printed)
