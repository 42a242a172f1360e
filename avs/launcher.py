"""Start the router and the services as local processes; watch, restart and stop them.

This is ``avs up``: the same commands compose.yaml runs, with every service connecting as a
client to the in-process router on loopback, multicast off.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field

import zenoh

from avs.router import open_router
from avs.services import ServiceInfo
from schemas.keys import Keys

log = logging.getLogger("avs.up")

#: restarts of one service before ``avs up`` gives up on it
MAX_RESTARTS = 3


def threads_per_instance(instances: int) -> int:
    """Compute threads for each of ``instances`` copies of a service on this host: the cores
    shared out (one worker's numba kernels would otherwise take every core, and two would
    fight over them)."""
    return max(1, (os.cpu_count() or 1) // instances)


@dataclass
class Child:
    info: ServiceInfo
    instance: str
    process: subprocess.Popen | None = None
    restarts: int = 0
    alive: bool = False
    active: bool = False  # its service's token is up
    standing_by: bool = False  # its standby token is up (services/common/standby.py)
    failed: bool = False
    started_at: float = field(default_factory=time.monotonic)


class Supervisor:
    """Owns the router session and one process per service instance."""

    def __init__(
        self,
        services: list[ServiceInfo],
        endpoint: str,
        robot: str = "armar6",
        env: dict[str, str] | None = None,
        restart: bool = True,
        scale: dict[str, int] | None = None,
        launch: dict[str, list[str]] | None = None,
    ) -> None:
        """``scale``: instances per service (default one each; only scalable services take
        more). ``launch``: a command prefix per service, e.g. ``ip netns exec HOST`` to run it
        in a network namespace of its own (tests/test_multihost.py)."""
        self.launch = launch or {}
        self.endpoint = endpoint
        self.keys = Keys(robot)
        self.robot = robot
        self.extra_env = env or {}
        self.restart = restart
        scale = scale or {}
        for name, n in scale.items():
            info = next((s for s in services if s.name == name), None)
            if info is None or n < 1 or (n > 1 and not info.scalable):
                raise ValueError(f"cannot run {n} instances of {name!r}: only started, scalable "
                                 "services take more than one")  # fmt: skip
        self.children = [
            Child(s, f"{s.name}-{i}") for s in services for i in range(scale.get(s.name, 1))
        ]
        self.router: zenoh.Session | None = None
        self._alive_sub = None
        self._changed = threading.Condition()

    # -- start --------------------------------------------------------------------------------

    def child_env(self, child: Child) -> dict[str, str]:
        env = dict(os.environ)
        env.update(
            AVS_MODE="client",
            AVS_CONNECT=self.endpoint,
            AVS_MULTICAST="false",
            AVS_ROBOT=self.robot,
            AVS_INSTANCE=child.instance,
        )
        env.setdefault("MUJOCO_GL", "egl")
        siblings = sum(1 for c in self.children if c.info.name == child.info.name)
        if siblings > 1 and "NUMBA_NUM_THREADS" not in os.environ:
            env["NUMBA_NUM_THREADS"] = str(threads_per_instance(siblings))
        env.update(self.extra_env)
        return env

    def _on_liveliness(self, sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")  # avs/<robot>/alive/<service>/<instance>
        if len(parts) != 5:
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        service = parts[3].removesuffix("_standby")  # a standby instance is up, too
        with self._changed:
            for child in self.children:
                if child.info.name == service and child.instance == parts[4]:
                    if service == parts[3]:
                        child.active = alive
                    else:
                        child.standing_by = alive
                    child.alive = child.active or child.standing_by
            self._changed.notify_all()

    def _spawn(self, child: Child) -> None:
        prefix = self.launch.get(child.info.name, [])
        child.process = subprocess.Popen(
            [*prefix, sys.executable, *child.info.argv()], env=self.child_env(child)
        )
        child.started_at = time.monotonic()
        log.info("started %s (pid %d)", child.instance, child.process.pid)

    def start(self) -> None:
        self.router = open_router([self.endpoint])
        log.info("router listening on %s", self.endpoint)
        self._alive_sub = self.router.liveliness().declare_subscriber(
            self.keys.alive(), self._on_liveliness, history=True
        )
        for child in self.children:
            self._spawn(child)

    def _ready(self) -> bool:
        """Every instance is up (its token, or its standby token), and every service has an
        active one (a service whose instances all stand by is not serving yet)."""
        if not all(c.alive or c.failed for c in self.children):
            return False
        services = {c.info.name for c in self.children if not c.failed}
        return all(any(c.active for c in self.children if c.info.name == s) for s in services)

    def wait_ready(self, timeout: float) -> bool:
        """Block until every service has declared its liveliness token, or ``timeout``."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while not self._ready():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self._changed.wait(min(remaining, 0.2))
                self.poll()
        return all(c.alive for c in self.children)

    # -- watch --------------------------------------------------------------------------------

    def poll(self) -> None:
        """Restart a service that exited on its own (up to ``MAX_RESTARTS`` times)."""
        for child in self.children:
            p = child.process
            if p is None or p.poll() is None or child.failed:
                continue
            if not self.restart or child.restarts >= MAX_RESTARTS:
                log.error("%s exited with status %d; not restarting", child.instance, p.returncode)
                child.failed = True
                continue
            child.restarts += 1
            log.warning(
                "%s exited with status %d; restart %d of %d",
                child.instance,
                p.returncode,
                child.restarts,
                MAX_RESTARTS,
            )
            self._spawn(child)

    def run_until(self, stop: threading.Event) -> None:
        while not stop.wait(0.5):
            self.poll()
            if self.children and all(c.failed for c in self.children):
                log.error("every service has failed")
                return

    # -- stop ---------------------------------------------------------------------------------

    def stop(self, grace: float = 10.0) -> None:
        """SIGTERM every service, wait up to ``grace`` seconds, SIGKILL what is left, close the
        router."""
        running = [c.process for c in self.children if c.process and c.process.poll() is None]
        for p in running:
            p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace
        for p in running:
            try:
                p.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("pid %d did not stop in %.0f s; killing it", p.pid, grace)
                p.kill()
                p.wait()
        if self._alive_sub is not None:
            self._alive_sub.undeclare()
        if self.router is not None:
            self.router.close()
            self.router = None
        log.info("stopped")

    def report(self) -> list[dict]:
        return [
            {
                "service": c.info.name,
                "instance": c.instance,
                "pid": c.process.pid if c.process else None,
                "alive": c.alive,
                "restarts": c.restarts,
            }
            for c in self.children
        ]
