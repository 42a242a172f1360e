"""The explorer in lockstep (``AVS_EXPLORER_CLOCK=lockstep``): it steps the sim while the
platform and head move and asks it to render each view; nothing else steps. Run twice from
the same seed, the episode takes the same views (the states a step published are taken before
the next decision, and the clock of its decisions is sim time alone)."""

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
from tests.conftest import free_port, session_config, wait_for

KEYS = Keys()


def episode(procs, tmp_path, name: str) -> list[ExploreStatus]:
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
    lock = threading.Lock()

    def keep(sample) -> None:
        with lock:
            statuses.append(decode(sample.payload.to_bytes(), ExploreStatus))

    json.loads(up.stdout.readline())  # ready
    with zenoh.open(session_config("client", connect=[endpoint])) as session:
        session.declare_subscriber(KEYS.explore_status(), keep)
        (reply,) = session.get(KEYS.explore_control(),
                               payload=encode(ExploreControl(op="start")), timeout=10)  # fmt: skip
        assert decode(reply.ok.payload.to_bytes(), ExploreStatus).phase == "plan"
        wait_for(lambda: statuses and statuses[-1].phase == "done", 300, "the episode's end",
                 lambda: statuses[-1:])  # fmt: skip
    up.send_signal(signal.SIGINT)
    assert up.wait(60) == 0
    return statuses


@pytest.mark.timeout(700)
def test_lockstep_episodes_take_the_same_views(procs, tmp_path):
    t0 = time.monotonic()
    first = episode(procs, tmp_path, "a")
    took = time.monotonic() - t0
    second = episode(procs, tmp_path, "b")
    end = first[-1]
    assert end.clock == "lockstep" and end.reason in ("quality", "max_views"), end
    assert end.view >= 2, end

    def views(statuses: list[ExploreStatus]) -> list[tuple]:
        """Per view: its planned goal and target, its frame and what it realised."""
        return [(tuple(round(g, 6) for g in s.goal), s.frame_seq, round(s.realised_gain))
                for s in statuses if s.phase in ("plan", "done") and s.view > 0]  # fmt: skip

    print(f"a lockstep episode: {end.view} views, {end.reason}, {took:.0f} s")
    assert views(first) == views(second) and views(first)
