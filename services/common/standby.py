"""One active instance, the others on standby (a writer such as the scene memory): an instance
declares ``alive/<service>_standby/<instance>`` and waits while an ``alive/<service>/*`` token
is live; when none is (at start, or the active one's token went with its process), the
rendezvous owner among the standby instances takes over (services/common/membership.py), the
others go on waiting. The caller then restores its state, declares the service's token, and
only then undeclares the standby token it was handed (so that no instance ever sees neither
and takes over too)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import zenoh

from schemas.keys import Keys
from services.common.membership import owner

log = logging.getLogger("avs.standby")


def wait_for_turn(
    session: zenoh.Session,
    keys: Keys,
    service: str,
    instance: str,
    stopping: Callable[[], bool],
    discover_s: float = 1.5,
) -> zenoh.LivelinessToken | None:
    """Block until this instance is to be the active one (its standby token, to undeclare
    once the service's is declared), or ``stopping()`` (None)."""
    standby = f"{service}_standby"
    token = session.liveliness().declare_token(keys.alive(standby, instance))
    changed = threading.Event()
    seen: dict[str, set[str]] = {service: set(), standby: set()}
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        *_, kind, who = str(sample.key_expr).split("/")
        with lock:
            if sample.kind == zenoh.SampleKind.PUT:
                seen[kind].add(who)
            else:
                seen[kind].discard(who)
        changed.set()

    # the tokens as the router knows them, kept up to date (history: those already there)
    subs = [session.liveliness().declare_subscriber(keys.alive(s), on, history=True)
            for s in (service, standby)]  # fmt: skip

    def live(s: str) -> list[str]:
        with lock:
            return sorted(seen[s])

    try:
        time.sleep(discover_s)  # let instances started together see each other
        said, mine = False, 0
        while not stopping():
            active, waiting = live(service), live(standby)
            if not active and owner("active", [*waiting, instance]) == instance:
                mine += 1
                if mine == 2:  # the same answer twice, 0.1 s apart: no late joiner in between
                    log.info("taking over as the active %s", service, extra={"standby": waiting})
                    return token
                time.sleep(0.1)
                continue
            mine = 0
            if not said:
                log.info("standing by", extra={"active": active, "standby": waiting})
                said = True
            changed.wait(0.2)
            changed.clear()
        token.undeclare()
        return None
    finally:
        for sub in subs:
            sub.undeclare()
