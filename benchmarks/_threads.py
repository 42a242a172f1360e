"""Thread limits for the benchmarks' like-for-like runs: every OpenBLAS the process has loaded
(numpy's, scipy's) held to a number of threads through its own C API, as threadpoolctl does,
without it."""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

# OpenBLAS's (set, get) thread-count functions under the names its builds export them
_NAMES = (
    ("scipy_openblas_set_num_threads64_", "scipy_openblas_get_num_threads64_"),
    ("scipy_openblas_set_num_threads", "scipy_openblas_get_num_threads"),
    ("openblas_set_num_threads64_", "openblas_get_num_threads64_"),
    ("openblas_set_num_threads", "openblas_get_num_threads"),
)


def _openblas() -> list[tuple]:
    """(set, get) of each OpenBLAS loaded in this process."""
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    paths = {line.split()[-1] for line in maps.read_text().splitlines() if "openblas" in line}
    found = []
    for path in sorted(paths):
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        for set_name, get_name in _NAMES:
            if hasattr(lib, set_name) and hasattr(lib, get_name):
                found.append((getattr(lib, set_name), getattr(lib, get_name)))
                break
    return found


@contextmanager
def blas_threads(n: int) -> Iterator[int]:
    """Every loaded OpenBLAS on ``n`` threads while the block runs (then as it was); yields
    how many libraries it holds (0: none found, nothing held)."""
    import numpy  # noqa: F401  (its OpenBLAS loaded before we look)

    libs = _openblas()
    before = [get() for _, get in libs]
    for set_threads, _ in libs:
        set_threads(n)
    try:
        yield len(libs)
    finally:
        for (set_threads, _), count in zip(libs, before, strict=True):
            set_threads(count)
