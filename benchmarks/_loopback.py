"""What the benchmarks that start services as processes share: a free loopback endpoint, a
client config for it (AVS's transport defaults, multicast off), stopping the processes."""

from __future__ import annotations

import socket
import subprocess

import zenoh

from services.common.transport import tune


def free_endpoint() -> str:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def client_config(endpoint: str) -> zenoh.Config:
    config = tune(zenoh.Config())
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", f'["{endpoint}"]')
    config.insert_json5("scouting/multicast/enabled", "false")
    return config


def stop(procs: list[subprocess.Popen]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        p.wait(30)
