"""A thread that keeps a core busy beside a timed one, for the benchmarks that measure what a
service's other threads cost it: ``"python"`` holds the GIL while it spins (as a node's
network callbacks and handlers do), ``"compiled"`` releases it (a core taken, nothing else)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from numba import njit


@njit(nogil=True, cache=True)
def _spin(n: int) -> float:
    x = 0.0
    for i in range(n):
        x += np.sqrt(i)
    return x


@contextmanager
def busy_thread(kind: str | None) -> Iterator[None]:
    """A spinning thread of ``kind`` ("python", "compiled" or None: none) while the block runs."""
    if kind not in (None, "python", "compiled"):
        raise ValueError(f"busy thread kind {kind!r}")
    if kind is None:
        yield
        return
    _spin(10)  # compiled before the block, not in it
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            if kind == "python":
                sum(range(200))
            else:
                _spin(200_000)

    spinner = threading.Thread(target=spin, name=f"busy-{kind}", daemon=True)
    spinner.start()
    try:
        yield
    finally:
        stop.set()
        spinner.join()
