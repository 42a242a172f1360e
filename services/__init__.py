"""AVS services: each a package with a pure core, a thin node and a ``__main__``."""

import hashlib
import os
import shutil
import sys
import time
from pathlib import Path

# numba's parallel kernels on OpenMP (libgomp, which Open3D needs too): left to choose, numba
# tries first the TBB that Open3D bundles, finds it too old and says so on every command's
# console
os.environ.setdefault("NUMBA_THREADING_LAYER", "omp")
# ... whose idle threads sleep rather than spin: on a machine whose cores the services share,
# a spinning worker burns the time the others wait for (a kitchen frame's map update under
# load: 170 ms of CPU with two spinning threads, 104 ms passive, 102 ms on one thread)
os.environ.setdefault("OMP_WAIT_POLICY", "passive")


def numba_cache_dir(sources: Path = Path(__file__).parent) -> Path:
    """Where the compiled kernels are cached: a directory per version of the sources that
    define kernels. numba checks a cached kernel only against its own file, yet a kernel
    compiles in the helpers it calls from other files (``voxel_map.find`` into ``icp``,
    ``common.dda`` into the map and the planner): after a change to a helper alone, the old
    cache would run the old helper, silently. Keyed by all kernel sources, it cannot."""
    digest = hashlib.sha256()
    for path in sorted(sources.rglob("*.py")):
        text = path.read_bytes()
        if b"from numba import" in text:
            digest.update(path.relative_to(sources).as_posix().encode() + b"\0" + text)
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "avs" / "numba" / digest.hexdigest()[:16]


def _prune(current: Path, days: float = 2.0) -> None:
    """Remove the caches of other versions untouched for ``days`` (each some megabytes)."""
    try:
        for other in current.parent.iterdir():
            if other != current and time.time() - other.stat().st_mtime > days * 86400:
                shutil.rmtree(other, ignore_errors=True)
    except OSError:
        pass


if "NUMBA_CACHE_DIR" not in os.environ:
    _cache = numba_cache_dir()
    _prune(_cache)
    os.environ["NUMBA_CACHE_DIR"] = str(_cache)
    if "numba" in sys.modules:  # read at numba's import; set it where numba looks now
        sys.modules["numba"].config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
