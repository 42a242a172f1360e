"""Live exploration (issue 41): ``avs up --explore`` on the wall clock, every service a process
on a real router, nothing stepping the sim: the explorer plans, the platform drives, the gaze
holds the view's target, the frames are fused, and an outside evaluator (``avs score``) finds
the support graph. The planner is killed mid-episode (the supervisor restarts it; the episode
waits for it and goes on); a stop sends the platform a zero velocity at once."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from schemas import BasePose, BaseVelocity, ExploreControl, ExploreStatus, Keys, decode, encode
from tests.conftest import free_port, session_config, wait_for

AVS = [sys.executable, "-m", "avs.cli"]
KEYS = Keys()
SCENE = "tabletop_occluded"


class Watch:
    """The explorer's statuses, the platform's odometry and its velocity commands, as they come
    (arrival times on this process's monotonic clock)."""

    def __init__(self, session: zenoh.Session) -> None:
        self.lock = threading.Lock()
        self.statuses: list[ExploreStatus] = []
        self.halts: list[float] = []
        self.base: list[tuple[float, BasePose]] = []
        self.subs = [
            session.declare_subscriber(KEYS.explore_status(), self._status),
            session.declare_subscriber(KEYS.cmd_base(), self._command),
            session.declare_subscriber(KEYS.base_state(), self._base),
        ]

    def _status(self, sample) -> None:
        with self.lock:
            self.statuses.append(decode(sample.payload.to_bytes(), ExploreStatus))

    def _command(self, sample) -> None:
        at = time.monotonic()
        try:
            cmd = decode(sample.payload.to_bytes(), BaseVelocity)
        except Exception:  # a BaseGoal
            return
        if cmd.v_x == cmd.v_y == cmd.v_yaw == 0.0:
            with self.lock:
                self.halts.append(at)

    def _base(self, sample) -> None:
        with self.lock:
            self.base.append((time.monotonic(), decode(sample.payload.to_bytes(), BasePose)))

    def last(self) -> ExploreStatus | None:
        with self.lock:
            return self.statuses[-1] if self.statuses else None


def speed(watch: Watch) -> float:
    with watch.lock:
        b = watch.base[-1][1]
    return max(math.hypot(b.v_x, b.v_y), abs(b.v_yaw))


def control(session: zenoh.Session, op: str) -> ExploreStatus:
    for reply in session.get(KEYS.explore_control(), payload=encode(ExploreControl(op=op)),
                             timeout=10):  # fmt: skip
        return decode(reply.ok.payload.to_bytes(), ExploreStatus)
    raise AssertionError(f"explore/control {op}: no reply")


@pytest.mark.timeout(600)
def test_avs_up_explores_by_itself_survives_a_planner_crash_and_stops_at_once(procs, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    t0 = time.monotonic()
    up = procs.start(
        [*AVS, "up", "--explore", "--scene", SCENE, "--listen", endpoint,
         "--data-dir", str(tmp_path / "data"), "--ready-timeout", "120"],
        env={k: v for k, v in os.environ.items() if not k.startswith("AVS_")},
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    ready = json.loads(up.stdout.readline())
    pids = {s["service"]: s["pid"] for s in ready["services"]}
    with zenoh.open(session_config("client", connect=[endpoint])) as session:
        watch = Watch(session)
        # the planner killed once the first view is taken: the explorer waits for its restart
        wait_for(lambda: (s := watch.last()) is not None and s.view >= 1, 240, "the first view")
        os.kill(pids["nbv"], signal.SIGKILL)
        killed_at = watch.last().view
        wait_for(lambda: watch.last().phase == "done", 240 - (time.monotonic() - t0) + 60,
                 "the episode's end")  # fmt: skip
        took = time.monotonic() - t0
        end = watch.last()
        assert end.reason in ("quality", "max_views"), end
        assert end.view > killed_at, (killed_at, end)  # views after the planner came back
        assert took < 240 + 30, took  # start-up included
        phases = {s.phase for s in watch.statuses}
        assert {"plan", "move", "settle", "capture", "done"} <= phases, phases
        # an outside evaluator, from another process
        out = subprocess.run([*AVS, "score", "--scene", SCENE, "--json", "--connect", endpoint],
                             capture_output=True, text=True, timeout=120)  # fmt: skip
        assert out.returncode == 0, out.stderr
        score = json.loads(out.stdout)
        assert score["support_f1"] >= 0.9, score
        # another episode, stopped while the platform drives (pushed by this test, so that it
        # drives whatever the view): a zero velocity within 0.2 s, then at rest
        started = subprocess.run([*AVS, "explorer", "start", "--connect", endpoint],
                                 capture_output=True, text=True, timeout=60)  # fmt: skip
        assert started.returncode == 0 and started.stdout.startswith("episode 2: plan"), started
        wait_for(lambda: watch.last().episode == 2 and watch.last().phase == "settle", 120,
                 "the second episode settling")  # fmt: skip
        push = session.declare_publisher(KEYS.cmd_base())
        push.put(encode(BaseVelocity(seq=1, stamp=time.time(), v_x=0.3, timeout=3.0)))
        wait_for(lambda: speed(watch) > 0.1, 5, "the platform driving")
        n = len(watch.halts)
        sent = time.monotonic()
        stopped = control(session, "stop")
        assert (stopped.phase, stopped.reason) == ("done", "stopped")
        wait_for(lambda: len(watch.halts) > n, 5, "a zero velocity command")
        assert watch.halts[n] - sent <= 0.2, watch.halts[n] - sent
        wait_for(lambda: speed(watch) < 0.01, 3, "the platform at rest")  # braking at 0.5 m/s²
        said = subprocess.run([*AVS, "explorer", "status", "--connect", endpoint],
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        assert said.stdout.startswith("episode 2: done") and "stopped" in said.stdout, said
        again = subprocess.run([*AVS, "explorer", "pause", "--connect", endpoint],
                               capture_output=True, text=True, timeout=60)  # fmt: skip
        assert again.returncode == 0  # nothing to pause: said, not an error
    up.send_signal(signal.SIGINT)
    assert up.wait(60) == 0
