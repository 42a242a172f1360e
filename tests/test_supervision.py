"""``avs up``'s supervision with real service processes on a real router: a hung service
(SIGSTOP) is found by its silent heartbeat and restarted; one that keeps crashing is restarted
with a growing back-off and ``avs status`` exits non-zero naming it; a ``schemas/`` folder in
the working directory does not shadow AVS's packages; a wrong router address or password is one
line within 5 s."""

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

from avs import acl
from avs.launcher import HEARTBEAT_S, Supervisor, peer_listen
from avs.services import BY_NAME
from tests.conftest import ROOT, free_port, wait_for

AVS = [sys.executable, "-m", "avs.cli"]


@pytest.fixture
def supervised():
    made: list[Supervisor] = []

    def make(services: list[str], **kw) -> Supervisor:
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        s = Supervisor([BY_NAME[n] for n in services], endpoint, **kw)
        made.append(s)
        s.start()
        stop = threading.Event()
        thread = threading.Thread(target=s.run_until, args=(stop,), daemon=True)
        thread.start()
        s.stop_watching = stop  # type: ignore[attr-defined]
        return s

    yield make
    for s in made:
        s.stop_watching.set()  # type: ignore[attr-defined]
        s.stop()


@pytest.mark.timeout(180)
def test_a_hung_service_is_killed_and_restarted(supervised):
    s = supervised(["nbv"], hung_after=3.0)
    assert s.wait_ready(90), s.report()
    child = s.children[0]
    wait_for(lambda: child.last_heard is not None, 10, "the first heartbeat")
    hung = child.process
    os.kill(hung.pid, signal.SIGSTOP)  # alive to the OS, silent to everyone
    t0 = time.monotonic()
    wait_for(lambda: child.restarts == 1, 30, "the hung service's restart")
    found = time.monotonic() - t0
    print(f"hung service found and killed {found:.1f} s after SIGSTOP (hung_after 3 s)")
    # silent for 3 s since its last answer, which came up to a heartbeat (1 s) before SIGSTOP
    assert 3.0 - HEARTBEAT_S <= found <= 8.0, found
    assert hung.poll() == -signal.SIGKILL
    wait_for(lambda: child.state == "running" and child.process is not hung, 90,
             "the restarted service running")  # fmt: skip


@pytest.mark.timeout(240)
def test_a_crashing_service_is_restarted_with_back_off_and_status_names_it(supervised):
    """nbv with an invalid setting exits at start, every time: restarted again and again, each
    delay twice the last up to the cap; ``avs status`` exits 1 and says which is down."""
    s = supervised(["nbv"], env={"AVS_LOG_LEVEL": "LOUD"}, backoff=(0.1, 0.8), hung_after=None)
    child = s.children[0]
    exits: dict[int, float] = {}  # pid → when its exit was seen
    delays: list[float] = []  # exit seen → the next process started
    seen = child.process

    def watch() -> bool:
        nonlocal seen
        p = child.process
        if p is not seen:
            if seen is not None and seen.pid in exits:
                delays.append(time.monotonic() - exits[seen.pid])
            seen = p
        elif p is not None and p.poll() is not None and p.pid not in exits:
            exits[p.pid] = time.monotonic()
        return child.restarts >= 10

    deadline = time.monotonic() + 180
    while not watch():  # watched closely: each delay is the measurement
        assert time.monotonic() < deadline, f"ten restarts: {s.report()}"
        time.sleep(0.005)
    assert child.state in ("backoff", "starting") and not child.failed
    out = subprocess.run([*AVS, "status", "--connect", s.endpoint], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert out.returncode == 1, out
    assert "nbv (nbv-0) is down" in out.stderr, out.stderr
    rows = subprocess.run([*AVS, "status", "--json", "--connect", s.endpoint],
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    down = [json.loads(line) for line in rows.stdout.splitlines()]
    assert down and down[0]["down"] and down[0]["restarts"] >= 10
    # each delay twice the last, up to the cap (plus the supervisor's 0.2 s poll)
    print("restart delays", [round(d, 2) for d in delays])
    assert len(delays) >= 8
    assert delays[0] < 0.6 and delays[1] < 0.7, delays  # 0.1 s, 0.2 s
    assert all(0.75 < d < 1.4 for d in delays[4:9]), delays  # 0.8 s: the cap


@pytest.mark.timeout(120)
def test_status_names_an_expected_service_that_is_not_live(supervised):
    s = supervised(["nbv"])
    assert s.wait_ready(90), s.report()
    ok = subprocess.run([*AVS, "status", "--connect", s.endpoint], capture_output=True,
                        text=True, timeout=60)  # fmt: skip
    assert ok.returncode == 0, ok.stderr
    missing = subprocess.run([*AVS, "status", "--connect", s.endpoint, "--expect", "nbv,gaze"],
                             capture_output=True, text=True, timeout=60)  # fmt: skip
    assert missing.returncode == 1
    assert "gaze (*) is down: not live" in missing.stderr and "nbv" not in missing.stderr


@pytest.mark.timeout(180)
def test_a_schemas_folder_in_the_working_directory_does_not_break_up(procs, tmp_path):
    """``avs schema export schemas`` leaves a schemas/ folder; services started from there must
    still import AVS's own package."""
    (tmp_path / "schemas").mkdir()
    (tmp_path / "schemas" / "__init__.py").write_text("raise ImportError('the wrong schemas')\n")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = dict(os.environ, PYTHONPATH=str(ROOT))  # avs itself found, as when installed
    up = procs.start(  # -P: as the installed ``avs`` script runs, without the cwd on sys.path
        [sys.executable, "-P", "-m", "avs.cli", "up", "--listen", endpoint,
         "--data-dir", str(tmp_path / "data"), "--services", "nbv", "--ready-timeout", "90"],
        env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    ready = json.loads(up.stdout.readline())
    assert [c["alive"] for c in ready["services"]] == [True], ready
    assert [c["restarts"] for c in ready["services"]] == [0]
    up.send_signal(signal.SIGINT)
    assert up.wait(30) == 0


@pytest.fixture
def secured_router(tmp_path):
    creds = tmp_path / "credentials.txt"
    creds.write_text("observer:right-password\n")
    config = zenoh.Config.from_file(str(ROOT / "deploy" / "zenoh" / "router-tcp.json5"))
    port = free_port()
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(creds)))
    with zenoh.open(config):
        yield f"tcp/127.0.0.1:{port}"


def _one_line_failure(args: list[str]) -> tuple[str, float]:
    t0 = time.monotonic()
    out = subprocess.run([*AVS, *args], capture_output=True, text=True, timeout=60)
    took = time.monotonic() - t0
    assert out.returncode != 0, out
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr, out.stderr
    return lines[0], took


@pytest.mark.parametrize("command", [["status"], ["echo", "sensors/imu"]], ids=" ".join)
def test_nothing_listening_is_one_line_naming_the_endpoint(command):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    line, took = _one_line_failure([*command, "--connect", endpoint])
    assert endpoint in line and line.startswith("avs: cannot connect"), line
    assert took < 5 + 3, took  # (the interpreter's start included)


def test_a_wrong_password_is_one_line_naming_the_endpoint_and_user(secured_router):
    line, took = _one_line_failure(["echo", "sensors/imu", "--connect", secured_router,
                                    "--user", "observer", "--password", "wrong"])  # fmt: skip
    assert secured_router in line and "'observer'" in line, line
    assert took < 5 + 3, took
    assert "observer" in acl.identities()


def test_avs_up_services_join_as_peers_and_compose_wiring_stays_clients():
    """``peers``: each service a Zenoh peer of the router, listening on the router's host on a
    port the OS picks (the services link to each other directly); without it, clients."""
    endpoint = "tcp/127.0.0.1:17447"
    peer = Supervisor([BY_NAME["nbv"]], endpoint, peers=True)
    env = peer.child_env(peer.children[0])
    assert (env["AVS_MODE"], env["AVS_CONNECT"], env["AVS_LISTEN"]) == (
        "peer", endpoint, "tcp/127.0.0.1:0")  # fmt: skip
    client = Supervisor([BY_NAME["nbv"]], endpoint)
    env = client.child_env(client.children[0])
    assert env["AVS_MODE"] == "client"


def test_scaled_workers_share_the_cores_and_a_standby_does_not_take_a_share(monkeypatch):
    """Instances that work side by side (perception) share the host's cores out among their
    numba threads; the scene memory's standby waits idle, so the active one gets every core."""
    monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    sup = Supervisor([BY_NAME["perception"], BY_NAME["scene_memory"], BY_NAME["nbv"]],
                     "tcp/127.0.0.1:17447", scale={"perception": 2, "scene_memory": 2})  # fmt: skip
    threads = {c.instance: sup.child_env(c).get("NUMBA_NUM_THREADS") for c in sup.children}
    assert threads == {"perception-0": "2", "perception-1": "2", "scene_memory-0": None,
                       "scene_memory-1": None, "nbv-0": None}  # fmt: skip


@pytest.mark.parametrize(
    ("endpoint", "listen"),
    [
        ("tcp/127.0.0.1:7447", "tcp/127.0.0.1:0"),
        ("tcp/[::1]:7447", "tcp/[::1]:0"),
        ("tls/robot.local:7447?iface=eth0", "tls/robot.local:0"),
        ("unixsock-stream//tmp/avs.sock", None),  # no ports: the services stay clients
        ("tcp/127.0.0.1", None),
    ],
)
def test_peers_listen_where_the_routers_transport_has_ports(endpoint, listen):
    assert peer_listen(endpoint) == listen
    sup = Supervisor([BY_NAME["nbv"]], endpoint, peers=True)
    env = sup.child_env(sup.children[0])
    assert env["AVS_MODE"] == ("peer" if listen else "client")
    assert env.get("AVS_LISTEN") == listen or listen is None
