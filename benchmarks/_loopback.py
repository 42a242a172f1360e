"""What the benchmarks that start services as processes share: a free loopback endpoint, a
client config for it (AVS's transport defaults, multicast off), stopping the processes."""

from __future__ import annotations

import os
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


def user_environment() -> dict[str, str]:
    """This process's environment without any ``AVS_*`` setting (the services run with their
    defaults, as ``avs up`` gives them to a user), rendering headless."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("AVS_")}
    dropped = sorted(set(os.environ) - set(env))
    if dropped:
        print(f"not passed on to avs up: {', '.join(dropped)}", flush=True)
    return env | {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
