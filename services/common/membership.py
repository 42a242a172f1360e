"""Who else is doing the same job: the live instances of a service (their liveliness tokens,
``alive/<service>/<instance>``), and rendezvous hashing over them (Thaler & Ravishankar 1998),
so that every instance agrees, without talking, which one owns a piece of work: the one with
the highest hash of (instance, key). When an instance joins or leaves, only the keys it wins or
held move."""

from __future__ import annotations

import hashlib
import threading
from collections.abc import Iterable

import zenoh


def weight(instance: str, key: object) -> int:
    return int.from_bytes(hashlib.blake2b(f"{instance}\x00{key}".encode(), digest_size=8).digest())


def owner(key: object, instances: Iterable[str]) -> str | None:
    """The instance that owns ``key``: highest rendezvous weight (None without instances)."""
    return max(instances, key=lambda i: weight(i, key), default=None)


class Members:
    """The live instances of ``service`` (the robot's ``alive/<service>/*`` tokens), kept
    up to date by a liveliness subscriber; ``me`` always counts as live."""

    def __init__(self, session: zenoh.Session, alive_key: str, me: str) -> None:
        self.me = me
        self._lock = threading.Lock()
        self._live: set[str] = {me}
        self._sub = session.liveliness().declare_subscriber(alive_key, self._on, history=True)

    def _on(self, sample: zenoh.Sample) -> None:
        instance = str(sample.key_expr).rsplit("/", 1)[-1]
        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._live.add(instance)
            elif instance != self.me:
                self._live.discard(instance)

    def current(self) -> list[str]:
        with self._lock:
            return sorted(self._live)

    def owns(self, key: object) -> bool:
        return owner(key, self.current()) == self.me

    def close(self) -> None:
        self._sub.undeclare()
