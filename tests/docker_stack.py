"""compose.host.yaml run for real by tests/test_compose.py: a compose project with its own
credentials and router port, an outside observer on the host, and what it saw, timed."""

from __future__ import annotations

import json
import os
import secrets
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import docker
import yaml
import zenoh

from avs.acl import identities
from schemas import Keys, RgbdFrame, SceneModel, SceneObservation, decode
from tests.conftest import ROOT, free_port, session_config

KEYS = Keys()
IMAGES = ("avs:latest", "avs-router:latest")
#: what the test run changes in compose.host.yaml: frames at a rate two perception containers
#: keep up with on two cores shared with the rest, a queue deep enough that none is superseded
#: and no pacing (``max_rate`` replaces a waiting frame by a newer one: with it, a survivor that
#: falls behind loses frames it owns), so each frame is processed by its owner: countable; no
#: real-time priorities (a benchmark may share the machine), a 2 cm map
TUNING = {
    "sim": {"AVS_SIM_FPS": "4", "AVS_SIM_REALTIME": "false"},
    "perception": {"AVS_PERCEPTION_QUEUE": "16", "AVS_PERCEPTION_MAX_RATE": "0"},
    "gaze": {"AVS_GAZE_REALTIME": "false"},
    "scene_memory": {"AVS_SCENE_MEMORY_VOXEL": "0.02"},
}


def compose_cli() -> list[str]:
    """``docker compose`` (v2) where the plugin is there, else ``docker-compose`` (1.x)."""
    v2 = subprocess.run(["docker", "compose", "version"], capture_output=True)
    return ["docker", "compose"] if v2.returncode == 0 else ["docker-compose"]


def docker_missing() -> str | None:
    """Why the live stack cannot run here, or None."""
    if shutil.which("docker") is None:
        return "no docker CLI"
    try:
        client = docker.from_env(timeout=10)
        client.ping()
    except docker.errors.DockerException as e:
        return f"no docker engine ({e})"
    missing = [i for i in IMAGES if not client.images.list(name=i)]
    return f"images missing: {missing}" if missing else None


@dataclass
class Seen:
    """What the observer received, each with its arrival time (monotonic)."""

    frames: list[tuple[float, int]] = field(default_factory=list)  # (t, seq)
    observations: list[tuple[float, int, str]] = field(default_factory=list)  # (t, seq, worker)
    models: list[tuple[float, int, int]] = field(default_factory=list)  # (t, version, primitives)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def since(self, t0: float, t1: float = float("inf")) -> Seen:
        with self.lock:
            return Seen(
                [f for f in self.frames if t0 <= f[0] < t1],
                [o for o in self.observations if t0 <= o[0] < t1],
                [m for m in self.models if t0 <= m[0] < t1],
            )


class Stack:
    """``docker compose -f compose.host.yaml`` as project ``name`` with fresh passwords and a
    free router port on 127.0.0.1; the router image is AVS's own (no registry here)."""

    def __init__(self, tmp: Path, name: str) -> None:
        self.name, self.tmp = name, tmp
        self.t_up = 0.0  # when `compose up` began (monotonic)
        self.port = free_port()
        self.passwords = {u: secrets.token_urlsafe(18) for u in identities()}
        config = tmp / "zenoh"
        config.mkdir()
        shutil.copy(ROOT / "deploy/zenoh/router-tcp.json5", config)
        (config / "credentials.txt").write_text(
            "".join(f"{u}:{p}\n" for u, p in self.passwords.items())
        )
        tuning: dict = {"router": {"volumes": [f"{config}:/etc/avs:ro"]}}
        tuning |= {s: {"environment": env} for s, env in TUNING.items()}
        (tmp / "tuning.yaml").write_text(yaml.safe_dump({"services": tuning}))
        passwords = {f"AVS_PASSWORD_{u.upper()}": p for u, p in self.passwords.items()}
        router = os.environ.get("AVS_ROUTER_IMAGE", IMAGES[1])
        self.env = dict(os.environ, AVS_PORT=str(self.port), AVS_ROUTER_IMAGE=router, **passwords)
        self.docker = docker.from_env(timeout=60)

    def compose(self, *args: str, timeout: float = 300) -> str:
        cmd = [*compose_cli(), "-p", self.name, "-f", str(ROOT / "compose.host.yaml"),
               "-f", str(self.tmp / "tuning.yaml"), *args]  # fmt: skip
        done = subprocess.run(cmd, env=self.env, cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout)  # fmt: skip
        assert done.returncode == 0, f"{' '.join(args)}: {done.stderr[-2000:]}"
        return done.stdout

    def containers(self, service: str | None = None, all: bool = False) -> list:
        labels = [f"com.docker.compose.project={self.name}"]
        if service:
            labels.append(f"com.docker.compose.service={service}")
        return self.docker.containers.list(all=all, filters={"label": labels})

    def session(self, user: str, wait_s: float = 60.0) -> zenoh.Session:
        """A client session as ``user``; the router container may still be starting (a test
        run alone right after ``compose up -d``): tried again for up to ``wait_s``."""
        config = session_config("client", connect=[f"tcp/127.0.0.1:{self.port}"])
        config.insert_json5("transport/auth/usrpwd/user", json.dumps(user))
        config.insert_json5("transport/auth/usrpwd/password", json.dumps(self.passwords[user]))
        deadline = time.monotonic() + wait_s
        while True:
            try:
                return zenoh.open(config)
            except zenoh.ZError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(1.0)


def watch(session: zenoh.Session) -> tuple[Seen, list]:
    """Subscribe to the frames, the observations and the scene model."""
    seen = Seen()

    def on_frame(s: zenoh.Sample) -> None:
        frame = decode(s.payload.to_bytes(), RgbdFrame)
        with seen.lock:
            seen.frames.append((time.monotonic(), frame.seq))

    def on_observation(s: zenoh.Sample) -> None:
        obs = decode(s.payload.to_bytes(), SceneObservation)
        with seen.lock:
            seen.observations.append((time.monotonic(), obs.frame_seq, obs.worker))

    def on_model(s: zenoh.Sample) -> None:
        model = decode(s.payload.to_bytes(), SceneModel)
        with seen.lock:
            seen.models.append((time.monotonic(), model.model_version, len(model.primitives)))

    subs = [session.declare_subscriber(KEYS.rgbd("head_rgbd"), on_frame),
            session.declare_subscriber(KEYS.observation(), on_observation),
            session.declare_subscriber(KEYS.scene(), on_model)]  # fmt: skip
    return seen, subs


def query(session: zenoh.Session, key: str, kind: type, payload: bytes | None = None):
    """The first valid reply to ``key``, or None."""
    for reply in session.get(key, payload=payload, timeout=3.0):
        if reply.ok:
            return decode(reply.ok.payload.to_bytes(), kind)
    return None
