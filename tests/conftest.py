"""Shared fixtures: a Zenoh router on a free loopback port, client sessions, child processes.

Every session here has multicast scouting off and explicit endpoints, so tests never find each
other (or anything else on the network).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

import services.sim  # noqa: F401  (first: it picks EGL before any test module imports mujoco)
from services.common.transport import tune

ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def session_config(mode: str, *, listen: list[str] = (), connect: list[str] = ()) -> zenoh.Config:
    config = tune(zenoh.Config())
    config.insert_json5("mode", json.dumps(mode))
    config.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect:
        config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return config


def wait_for(
    predicate: Callable[[], bool],
    timeout: float,
    what: str,
    state: Callable[[], object] | None = None,
) -> None:
    """Poll ``predicate`` until it holds; fail the test with ``what`` (and ``state()``, the
    situation at the time) after ``timeout``."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            detail = f" (state: {state()})" if state else ""
            pytest.fail(f"timed out after {timeout:.0f} s waiting for {what}{detail}")
        time.sleep(0.02)


@pytest.fixture
def router() -> Iterator[str]:
    """The endpoint of a Zenoh router running in this process."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = zenoh.open(session_config("router", listen=[endpoint]))
    yield endpoint
    session.close()


@pytest.fixture
def client(router: str) -> Iterator[zenoh.Session]:
    session = zenoh.open(session_config("client", connect=[router]))
    yield session
    session.close()


def avs_env(endpoint: str, **extra: str) -> dict[str, str]:
    env = dict(os.environ)
    env.update(AVS_MODE="client", AVS_CONNECT=endpoint, AVS_MULTICAST="false", **extra)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


class Processes:
    """Child processes started by a test; all are stopped at teardown."""

    def __init__(self) -> None:
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list[str], env: dict[str, str] | None = None, **kw) -> subprocess.Popen:
        p = subprocess.Popen(args, env=env, cwd=kw.pop("cwd", ROOT), **kw)
        self.procs.append(p)
        return p

    def python(self, args: list[str], env: dict[str, str] | None = None, **kw) -> subprocess.Popen:
        return self.start([sys.executable, *args], env=env, **kw)

    def stop_all(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture
def procs() -> Iterator[Processes]:
    p = Processes()
    yield p
    p.stop_all()


def matched_publisher(session: zenoh.Session, key: str, timeout: float = 10) -> zenoh.Publisher:
    """A publisher on ``key`` (congestion BLOCK) once a subscriber matches it: a put before the
    subscriber's declaration has reached the router would go nowhere."""
    publisher = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
    wait_for(lambda: publisher.matching_status.matching, timeout, f"a subscriber on {key}")
    return publisher


def liveliness_tokens(session: zenoh.Session, key: str) -> set[str]:
    return {str(r.ok.key_expr) for r in session.liveliness().get(key, timeout=2.0) if r.ok}


def collect(session: zenoh.Session, key: str) -> tuple[list[zenoh.Sample], threading.Lock]:
    """Subscribe to ``key``; the returned list fills with samples as they arrive."""
    samples: list[zenoh.Sample] = []
    lock = threading.Lock()

    def on_sample(s: zenoh.Sample) -> None:
        with lock:
            samples.append(s)

    session.declare_subscriber(key, on_sample)
    return samples, lock
