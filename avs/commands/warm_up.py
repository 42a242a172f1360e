"""``avs warm-up``: compile every service's numba kernels into the cache
(``~/.cache/avs/numba/<digest of the kernels' sources>``), as each service's own warm-up does
at its start. The image build runs it, so a container starts in seconds rather than compiling
for tens of seconds (six at once on a small machine); on a host it spares the first episode
the same wait. Each service's kernels are compiled by the warm-up its node runs, with the
settings it would read (environment, defaults), so the cache holds what the node will ask for."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed


def _perception() -> None:
    from services.perception.pipeline import Perception

    Perception().warm_up()


def _scene_memory() -> None:
    from services.scene_memory import kernels

    kernels.warm_up()


def _nbv() -> None:
    from services.nbv.config import NbvSettings
    from services.nbv.node import build_planner

    build_planner(NbvSettings.from_args([])).warm_up()


def _gaze() -> None:
    from services.gaze.config import GazeSettings
    from services.gaze.node import build_stabiliser

    build_stabiliser(GazeSettings.from_args([])).warm_up()


#: each service's warm-up, the longest first (nbv 27, scene memory 26, perception 20, gaze 12 s
#: on one core here): with ``--jobs`` the last to start is a short one
WARM_UPS: dict[str, Callable[[], None]] = {
    "nbv": _nbv,
    "scene_memory": _scene_memory,
    "perception": _perception,
    "gaze": _gaze,
}
SERVICES = tuple(WARM_UPS)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "warm-up", help="compile every service's kernels into the cache", description=__doc__
    )
    p.add_argument(
        "services", nargs="*", metavar="SERVICE",
        help=f"only these ({', '.join(SERVICES)}; default all)",
    )  # fmt: skip
    p.add_argument(
        "--jobs", type=int, default=1, metavar="N",
        help="compile N services at a time, each in a process of its own (default 1)",
    )  # fmt: skip
    p.set_defaults(func=_run, parser=p)


def _run(args: argparse.Namespace) -> int:
    import services  # noqa: F401  (sets NUMBA_CACHE_DIR)

    names = args.services or list(SERVICES)
    unknown = sorted(set(names) - set(SERVICES))
    if unknown:
        args.parser.error(f"no kernels to compile for {', '.join(unknown)} (one of {SERVICES})")
    print(f"compiling the kernels of {', '.join(names)} into {os.environ['NUMBA_CACHE_DIR']}")
    if args.jobs <= 1:
        for name in names:
            t0 = time.perf_counter()
            WARM_UPS[name]()
            print(f"  {name}: {time.perf_counter() - t0:.1f} s", flush=True)
        return 0
    return _in_processes(names, args.jobs)


def _in_processes(names: list[str], jobs: int) -> int:
    """Each service's warm-up in a process of its own, ``jobs`` at a time. Their kernels are
    apart, so none waits on another's compilation of the same kernel."""

    def warm(name: str) -> tuple[str, int, float]:
        t0 = time.perf_counter()
        command = [sys.executable, "-m", "avs.cli", "warm-up", name]
        code = subprocess.run(command, stdout=subprocess.DEVNULL).returncode
        return name, code, time.perf_counter() - t0

    failed = []
    with ThreadPoolExecutor(jobs) as pool:
        for done in as_completed([pool.submit(warm, n) for n in WARM_UPS if n in names]):
            name, code, seconds = done.result()
            print(f"  {name}: {seconds:.1f} s", flush=True)
            if code:
                failed.append(name)
    if failed:
        print(f"the warm-up of {', '.join(failed)} failed (its error above)", file=sys.stderr)
    return 1 if failed else 0
