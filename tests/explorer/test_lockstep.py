"""The explorer in lockstep (``AVS_EXPLORER_CLOCK=lockstep``): it steps the sim while the
platform and head move and asks it to render each view; nothing else steps. Run twice from
the same seed, the episode takes the same views at the same sim times (the states a step
published are taken before the next decision, and the clock of its decisions is sim time
alone). What the views realise is not compared: the scene memory's map and registration are
not bit-reproducible under load (33839 against 33675 voxels at a view in one CI run)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time

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


@pytest.mark.timeout(700)
def test_lockstep_episodes_take_the_same_views(procs, tmp_path):
    t0 = time.monotonic()
    first, first_frames = episode(procs, tmp_path, "a")
    took = time.monotonic() - t0
    second, second_frames = episode(procs, tmp_path, "b")
    end = first[-1]
    assert end.clock == "lockstep" and end.reason in ("quality", "max_views"), end
    assert end.view >= 2, end

    def views(statuses: list[ExploreStatus]) -> list[tuple]:
        """Per view: its planned goal and the frame taken."""
        return [(tuple(round(g, 6) for g in s.goal), s.frame_seq)
                for s in statuses if s.phase in ("plan", "done") and s.view > 0]  # fmt: skip

    print(f"a lockstep episode: {end.view} views, {end.reason}, {took:.0f} s; frames "
          f"{first_frames}")  # fmt: skip
    assert views(first) == views(second) and views(first)
    assert len(first_frames) == end.view and first_frames == second_frames
