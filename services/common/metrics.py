"""Counters and timings of a node: messages in / out per key, drops per reason, handler time."""

from __future__ import annotations

import threading
import time
from collections import defaultdict, deque
from contextlib import contextmanager

import numpy as np

from schemas.runtime import ServiceMetrics, TimingSummary

#: handler timings kept for the percentiles
WINDOW = 4096


class Metrics:
    def __init__(self, service: str, instance: str) -> None:
        self.service, self.instance = service, instance
        self.started = time.monotonic()
        self._lock = threading.Lock()
        self._in: dict[str, int] = defaultdict(int)
        self._valid: dict[str, int] = defaultdict(int)
        self._out: dict[str, int] = defaultdict(int)
        self._dropped: dict[str, int] = defaultdict(int)
        self._timings: dict[str, deque[float]] = defaultdict(lambda: deque(maxlen=WINDOW))
        self._gauges: dict[str, float] = {}
        self._seq = 0

    def count_in(self, key: str, n: int = 1) -> None:
        with self._lock:
            self._in[key] += n

    def count_valid(self, key: str) -> None:
        """An input on ``key`` that decoded and validated."""
        with self._lock:
            self._valid[key] += 1

    def count_out(self, key: str) -> None:
        with self._lock:
            self._out[key] += 1

    def drop(self, reason: str) -> bool:
        """Count a dropped message; True the first time this reason occurs."""
        with self._lock:
            self._dropped[reason] += 1
            return self._dropped[reason] == 1

    def drop_n(self, reason: str, n: int) -> None:
        """Count ``n`` messages dropped for ``reason`` at once (e.g. superseded by a newer)."""
        with self._lock:
            self._dropped[reason] += n

    def record(self, handler: str, seconds: float) -> None:
        with self._lock:
            self._timings[handler].append(seconds * 1e3)

    @contextmanager
    def timed(self, handler: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.record(handler, time.perf_counter() - t0)

    def add(self, name: str, n: float) -> bool:
        """Add ``n`` to the gauge ``name`` (a running count); True the first time."""
        with self._lock:
            first = name not in self._gauges
            self._gauges[name] = self._gauges.get(name, 0.0) + float(n)
            return first

    def gauge(self, name: str, value: float) -> None:
        with self._lock:
            self._gauges[name] = float(value)

    @property
    def dropped_total(self) -> int:
        with self._lock:
            return sum(self._dropped.values())

    def snapshot(self) -> ServiceMetrics:
        with self._lock:
            timings = {k: np.fromiter(v, float) for k, v in self._timings.items() if v}
            self._seq += 1
            return ServiceMetrics(
                seq=self._seq,
                stamp=time.time(),
                service=self.service,
                instance=self.instance,
                uptime_s=time.monotonic() - self.started,
                messages_in=dict(self._in),
                messages_valid=dict(self._valid),
                messages_out=dict(self._out),
                dropped=dict(self._dropped),
                processing_ms={
                    k: TimingSummary(
                        count=len(t),
                        p50=float(np.percentile(t, 50)),
                        p90=float(np.percentile(t, 90)),
                        p99=float(np.percentile(t, 99)),
                        max=float(t.max()),
                    )
                    for k, t in timings.items()
                },
                extra=dict(self._gauges),
            )
