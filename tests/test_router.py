"""``python -m avs.router``, the router image's entry point: zenohd's -c/-l on the shipped
config, its password check and access control, and a clean exit on SIGTERM (it is PID 1)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest
import zenoh

from tests.conftest import ROOT, free_port, session_config, wait_for


def _login(endpoint: str, user: str, password: str) -> zenoh.Session:
    config = session_config("client", connect=[endpoint])
    config.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
    config.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
    return zenoh.open(config)


@pytest.mark.timeout(60)
def test_the_router_entry_point_serves_the_shipped_config(tmp_path):
    (tmp_path / "credentials.txt").write_text("observer:seen\noperator:op\n")
    text = (ROOT / "deploy/zenoh/router-tcp.json5").read_text()
    config = tmp_path / "router.json5"
    config.write_text(text.replace("/etc/avs/credentials.txt", str(tmp_path / "credentials.txt")))
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    args = [sys.executable, "-m", "avs.router", "-c", str(config), "-l", endpoint]
    router = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE, text=True)
    key = "avs/armar6/cmd/base"
    try:
        assert "up (config" in router.stderr.readline()
        with pytest.raises(zenoh.ZError):
            _login(endpoint, "observer", "wrong")
        got: list[bytes] = []
        with _login(endpoint, "observer", "seen") as observer:
            observer.declare_subscriber(key, lambda s: got.append(s.payload.to_bytes()))
            other = _login(endpoint, "observer", "seen")
            operator = _login(endpoint, "operator", "op")
            other.put(key, b"denied")  # an observer publishes nothing (another session's)
            publisher = operator.declare_publisher(key)
            wait_for(lambda: publisher.matching_status.matching, 10, "the subscriber")
            publisher.put(b"ok")
            wait_for(lambda: got, 10, "the operator's put")
            time.sleep(0.5)
            other.close()
            operator.close()
        assert got == [b"ok"]
    finally:
        router.send_signal(signal.SIGTERM)
        assert router.wait(10) == 0
