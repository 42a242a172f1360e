"""Start the router and the services as local processes; watch, restart and stop them.

This is ``avs up``: the same commands compose.yaml runs, with every service connecting as a
client to the in-process router on loopback, multicast off.

Supervision: a service that exits is restarted after a back-off that doubles with every quick
failure (0.5 s, 1 s, 2 s … 30 s) and starts over once it has run ``HEALTHY_S``; a service
whose metrics queryable has not answered for ``hung_after`` seconds (alive but stuck: a
deadlock, SIGSTOP: stopped, or spending no CPU time) is killed and restarted the same way; one
that answers late because busier processes starve it is left alone. The state of every
instance is served on ``avs/<robot>/supervisor`` (``avs status`` reads it as the expected set).
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
from pathlib import Path

import zenoh

from avs.router import open_router
from avs.services import ServiceInfo
from schemas.codec import encode
from schemas.keys import Keys
from schemas.runtime import SupervisedService, SupervisorStatus
from services.common.realtime import prioritise

log = logging.getLogger("avs.up")

#: the first restart's delay and the longest one (it doubles with every quick failure)
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.5, 30.0
#: a service that ran this long has recovered: its next failure starts the back-off over
HEALTHY_S = 30.0
#: how often every service's metrics queryable is asked whether it still answers
HEARTBEAT_S = 1.0
#: default time without an answer after which a service counts as hung
HUNG_AFTER_S = 10.0


def threads_per_instance(instances: int) -> int:
    """Compute threads for each of ``instances`` copies of a service on this host: the cores
    shared out (one worker's numba kernels would otherwise take every core, and two would
    fight over them)."""
    return max(1, (os.cpu_count() or 1) // instances)


def process_state(pid: int) -> tuple[str | None, float]:
    """(the process's state letter from /proc, e.g. R, S, T; its CPU seconds so far), or
    (None, 0) when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None, 0.0
    return fields[0], (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@dataclass
class Child:
    info: ServiceInfo
    instance: str
    process: subprocess.Popen | None = None
    restarts: int = 0
    streak: int = 0  # failures in a row, each within HEALTHY_S of its start
    next_start: float | None = None  # a restart waiting for its back-off
    last_heard: float | None = None  # its metrics queryable's last answer (monotonic)
    cpu_mark: tuple[float, float] | None = None  # (its CPU seconds, when) once it went silent
    state: str = "starting"
    alive: bool = False
    active: bool = False  # its service's token is up
    standing_by: bool = False  # its standby token is up (services/common/standby.py)
    failed: bool = False
    started_at: float = field(default_factory=time.monotonic)


#: transports whose endpoints are <host>:<port>, where a peer can listen on port 0
PORT_TRANSPORTS = ("tcp", "udp", "tls", "quic")


def peer_listen(endpoint: str) -> str | None:
    """The endpoint a peer beside the router at ``endpoint`` listens on: the router's
    transport and host, port 0 (the OS picks one); None where the transport has no ports
    (a unix socket): the services stay clients of the router there."""
    proto, _, address = endpoint.partition("/")
    address = address.split("?", 1)[0].split("#", 1)[0]
    host, sep, port = address.rpartition(":")
    if proto not in PORT_TRANSPORTS or not sep or not host or not port.isdigit():
        return None
    return f"{proto}/{host}:0"


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
        hung_after: float | None = HUNG_AFTER_S,
        backoff: tuple[float, float] = (BACKOFF_MIN_S, BACKOFF_MAX_S),
        realtime: bool = False,
        peers: bool = False,
        log_dir: Path | None = None,
    ) -> None:
        """``scale``: instances per service (default one each; only scalable services take
        more). ``launch``: a command prefix per service, e.g. ``ip netns exec HOST`` to run it
        in a network namespace of its own (tests/test_multihost.py). ``hung_after``: seconds
        without a heartbeat before a running service is restarted (None: never; only with
        ``restart``). ``backoff``: the first and the longest restart delay, seconds.
        ``realtime``: real-time scheduling for the router's threads (``avs up``). ``peers``:
        the services join as Zenoh peers (connected to the router, and to each other directly
        over loopback as they learn of each other through it) instead of clients: a message
        between two services then crosses one link instead of two, and the router carries only
        what outside clients ask for (on this 2-core machine the router's share fell from about
        a fifth of a core to 4 %). Only where every service runs on the router's host and no
        access control is wanted: peer links bypass the router's ACL (compose keeps clients).
        ``log_dir``: each instance's output (stdout and stderr) goes to ``<service>.log`` there
        (``<instance>.log`` when a service runs several; begun anew at start, appended to across
        restarts) instead of this process's console."""
        self.backoff = backoff
        self.realtime = realtime
        self.peers = peers
        self.hung_after = hung_after if restart else None
        self.launch = launch or {}
        self.endpoint = endpoint
        self.keys = Keys(robot)
        self.robot = robot
        self.extra_env = env or {}
        self.restart = restart
        self.log_dir = log_dir
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
        self._status_queryable = None
        self._changed = threading.Condition()
        self._stopping = threading.Event()

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
        listen = peer_listen(self.endpoint) if self.peers else None
        if listen is not None:  # each listens on the router's host, on a port the OS picks
            env.update(AVS_MODE="peer", AVS_LISTEN=listen)
        env.setdefault("MUJOCO_GL", "egl")
        # the working directory must not shadow AVS's packages (a schemas/ folder there)
        env["PYTHONSAFEPATH"] = "1"
        siblings = sum(1 for c in self.children if c.info.name == child.info.name)
        # instances that work side by side share the cores out; a standby waits, idle, and
        # the one working takes every core (the live stack's scene memory ran its kernels on
        # one core of two while its standby's share sat unused)
        if siblings > 1 and not child.info.one_active and "NUMBA_NUM_THREADS" not in os.environ:
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

    def log_file(self, child: Child) -> Path | None:
        """Where ``child``'s output goes (None: this process's console)."""
        if self.log_dir is None:
            return None
        siblings = sum(1 for c in self.children if c.info.name == child.info.name)
        return self.log_dir / f"{child.info.name if siblings == 1 else child.instance}.log"

    def _spawn(self, child: Child) -> None:
        prefix = self.launch.get(child.info.name, [])
        path = self.log_file(child)
        out = None
        if path is not None:
            path.parent.mkdir(parents=True, exist_ok=True)
            mode = "wb" if child.process is None else "ab"  # a restart continues its log
            out = open(path, mode)  # noqa: SIM115 - the child holds it; ours closes below
        try:
            child.process = subprocess.Popen(
                [*prefix, sys.executable, *child.info.argv()],
                env=self.child_env(child),
                stdout=out,
                stderr=subprocess.STDOUT if out is not None else None,
            )
        finally:
            if out is not None:
                out.close()
        child.started_at = time.monotonic()
        child.last_heard, child.next_start, child.state = None, None, "starting"
        log.info("started %s (pid %d)", child.instance, child.process.pid)

    def start(self) -> None:
        self.router = open_router([self.endpoint])
        log.info("router listening on %s", self.endpoint)
        if self.realtime:  # the router carries the 1 kHz streams: its threads come first
            prioritise("the router", main_thread=False)
        self._alive_sub = self.router.liveliness().declare_subscriber(
            self.keys.alive(), self._on_liveliness, history=True
        )
        self._status_queryable = self.router.declare_queryable(
            self.keys.supervisor(), self._on_status_query
        )
        for child in self.children:
            self._spawn(child)
        threading.Thread(target=self._heartbeats, name="heartbeats", daemon=True).start()

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
        """Restart what exited (after its back-off) and what hung; keep every state current."""
        now = time.monotonic()
        for child in self.children:
            p = child.process
            if child.failed or p is None:
                continue
            if child.next_start is not None:
                if now >= child.next_start:
                    self._spawn(child)
                continue
            if p.poll() is None:
                if self._hung(child, now):
                    log.error("%s (pid %d) hung: no heartbeat for %.0f s; killing it",
                              child.instance, p.pid, now - (child.last_heard or now))  # fmt: skip
                    child.state = "hung"
                    p.kill()
                    p.wait()
                    self._schedule_restart(child, now, "was killed as hung")
                else:
                    up = "running" if child.active else "standby" if child.standing_by else None
                    child.state = up or "starting"
                continue
            self._schedule_restart(child, now, f"exited with status {p.returncode}")

    def _hung(self, child: Child, now: float) -> bool:
        """Alive by its process, silent on its metrics queryable for ``hung_after`` seconds
        after it had answered once (a service still starting up is not judged), and not
        working either: stopped (SIGSTOP), or no CPU time spent in that window (a deadlock).
        A process starved of CPU by busier ones answers late but is not hung."""
        if (
            self.hung_after is None
            or child.last_heard is None
            or child.process is None
            or now - child.last_heard <= self.hung_after
        ):
            child.cpu_mark = None
            return False
        state, cpu = process_state(child.process.pid)
        if state in ("T", "t", None):  # stopped, traced, or gone
            return True
        if child.cpu_mark is None or child.cpu_mark[1] < child.last_heard:
            child.cpu_mark = (cpu, now)  # the CPU time when the silence passed hung_after
            return False
        return cpu == child.cpu_mark[0] and now - child.cpu_mark[1] >= HEARTBEAT_S * 3

    def _schedule_restart(self, child: Child, now: float, why: str) -> None:
        if not self.restart or self._stopping.is_set():
            log.error("%s %s; not restarting", child.instance, why)
            child.failed, child.state = True, "failed"
            return
        if now - child.started_at >= HEALTHY_S:
            child.streak = 0  # it had recovered: this is a new failure, not one more in a row
        delay = min(self.backoff[1], self.backoff[0] * 2**child.streak)
        child.streak += 1
        child.restarts += 1
        child.next_start, child.state = now + delay, "backoff"
        child.alive = child.active = child.standing_by = False
        log.warning("%s %s; restart %d in %.1f s", child.instance, why, child.restarts, delay)

    def _heartbeats(self) -> None:
        """Ask every metrics queryable once a second; each answer is its instance's heartbeat
        (answered on Zenoh's threads: a busy service answers, a stuck one does not). The
        answers come to a callback: a thread blocked iterating a query's replies holds the GIL
        most of that time, and the supervisor's own queryable would wait for it."""
        while not self._stopping.wait(HEARTBEAT_S):
            router = self.router
            if router is None:
                return
            try:
                router.get(self.keys.metrics(), self._on_heartbeat, timeout=HEARTBEAT_S)
            except zenoh.ZError:
                return  # the router closed

    def _on_heartbeat(self, reply: zenoh.Reply) -> None:
        if reply.ok is None:
            return
        parts = str(reply.ok.key_expr).split("/")  # avs/<robot>/metrics/<service>/<instance>
        if len(parts) != 5:
            return
        now = time.monotonic()
        for child in self.children:
            if child.info.name == parts[3] and child.instance == parts[4]:
                child.last_heard = now

    def status(self) -> SupervisorStatus:
        now = time.monotonic()
        return SupervisorStatus(
            seq=0,
            stamp=time.time(),
            services=[
                SupervisedService(
                    service=c.info.name,
                    instance=c.instance,
                    pid=c.process.pid if c.process and c.process.poll() is None else None,
                    state=c.state,
                    alive=c.alive,
                    restarts=c.restarts,
                    uptime_s=max(0.0, now - c.started_at) if c.state != "backoff" else 0.0,
                )
                for c in self.children
            ],
        )

    def _on_status_query(self, query: zenoh.Query) -> None:
        query.reply(self.keys.supervisor(), encode(self.status()))

    def run_until(self, stop: threading.Event) -> None:
        while not stop.wait(0.2):
            self.poll()
            if self.children and all(c.failed for c in self.children):
                log.error("every service has failed")
                return

    # -- stop ---------------------------------------------------------------------------------

    def stop(self, grace: float = 10.0) -> None:
        """SIGTERM every service, wait up to ``grace`` seconds, SIGKILL what is left, close the
        router."""
        self._stopping.set()
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
        for entity in (self._alive_sub, self._status_queryable):
            if entity is not None:
                entity.undeclare()
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
                "state": c.state,
            }
            for c in self.children
        ]
