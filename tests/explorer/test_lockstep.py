"""The explorer in lockstep (``AVS_EXPLORER_CLOCK=lockstep``): it steps the sim while the
platform and head move and asks it to render each view; nothing else steps: one rendered
frame per view, the sim's clock standing still while it plans and waits for fusion.

Two runs are not compared: on an idle machine they take the same views at the same sim
times, but under the full suite's load the scene memory's map is not bit-reproducible (33839
against 33675 voxels realised at one view; a third view's goal differed in another run), and
the plans that follow from it differ."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from itertools import pairwise

import pytest
import zenoh

from schemas import ExploreControl, ExploreStatus, Keys, decode, encode
from schemas.codec import peek
from tests.conftest import free_port, session_config, wait_for

KEYS = Keys()


def episode(procs, tmp_path, name: str) -> tuple[list[ExploreStatus], list[tuple[int, float]]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {k: v for k, v in os.environ.items() if not k.startswith("AVS_")}
    env |= {"AVS_SIM_LOCKSTEP": "true", "AVS_EXPLORER_CLOCK": "lockstep",
            "AVS_EXPLORER_VIEWS": "3", "AVS_EXPLORER_AUTOSTART": "false",
            "MUJOCO_GL": "egl"}  # fmt: skip
    up = procs.start(
        [sys.executable, "-m", "avs.cli", "up", "--explore", "--scene", "tabletop_occluded",
         "--services", "sim,perception,scene_memory,nbv,explorer", "--no-standby",
         "--listen", endpoint, "--data-dir", str(tmp_path / name)],
        env=env, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    statuses: list[ExploreStatus] = []
    frames: list[tuple[int, float]] = []  # (seq, sim time) of each rendered frame
    lock = threading.Lock()

    def keep(sample) -> None:
        with lock:
            statuses.append(decode(sample.payload.to_bytes(), ExploreStatus))

    def frame(sample) -> None:
        head = peek(sample.payload.to_bytes(), "seq", "stamp")
        with lock:
            frames.append((head["seq"], round(head["stamp"], 6)))

    json.loads(up.stdout.readline())  # ready
    with zenoh.open(session_config("client", connect=[endpoint])) as session:
        session.declare_subscriber(KEYS.explore_status(), keep)
        session.declare_subscriber(KEYS.rgbd("head_rgbd"), frame)
        (reply,) = session.get(KEYS.explore_control(),
                               payload=encode(ExploreControl(op="start")), timeout=10)  # fmt: skip
        assert decode(reply.ok.payload.to_bytes(), ExploreStatus).phase == "plan"
        wait_for(lambda: statuses and statuses[-1].phase == "done", 300, "the episode's end",
                 lambda: statuses[-1:])  # fmt: skip
    up.send_signal(signal.SIGINT)
    assert up.wait(60) == 0
    return statuses, frames


@pytest.mark.timeout(500)
def test_a_lockstep_episode_steps_the_sim_itself_and_renders_one_frame_per_view(procs, tmp_path):
    t0 = time.monotonic()
    statuses, frames = episode(procs, tmp_path, "a")
    end = statuses[-1]
    print(f"a lockstep episode: {end.view} views, {end.reason}, "
          f"{time.monotonic() - t0:.0f} s; frames {frames}")  # fmt: skip
    assert end.clock == "lockstep" and end.reason in ("quality", "max_views"), end
    assert end.view >= 2, end
    # one frame per view, rendered on the explorer's request, the sim's clock moving between
    # them only while the platform and head moved (a view's drive and settling: seconds)
    assert [seq for seq, _ in frames] == list(range(end.view)), frames
    times = [t for _, t in frames]
    assert all(b - a >= 0.3 for a, b in pairwise(times)), times
    goals = [tuple(s.goal) for s in statuses if s.phase == "move"]
    assert len(set(goals)) == end.view, goals  # each view planned once, none repeated
