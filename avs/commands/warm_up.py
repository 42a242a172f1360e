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

SERVICES = ("perception", "scene_memory", "nbv", "gaze")
#: their compilation times, longest first (26, 26, 20 and 12 s on one core here)
SERVICES_BY_COST = ("nbv", "scene_memory", "perception", "gaze")


def _perception() -> None:
    from services.perception.pipeline import Perception

    Perception().warm_up()


def _scene_memory() -> None:
    from services.scene_memory import fusion, occupancy, registration

    occupancy.warm_up()
    fusion.warm_up()
    registration.warm_up()


def _nbv() -> None:
    from services.nbv.config import NbvSettings
    from services.nbv.node import build_planner

    build_planner(NbvSettings.from_args([])).warm_up()


def _gaze() -> None:
    from services.gaze.config import GazeSettings
    from services.gaze.node import build_stabiliser

    build_stabiliser(GazeSettings.from_args([])).warm_up()


WARM_UPS: dict[str, Callable[[], None]] = {
    "perception": _perception,
    "scene_memory": _scene_memory,
    "nbv": _nbv,
    "gaze": _gaze,
}


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
    """Each service's warm-up in a process of its own, ``jobs`` at a time (the biggest first:
    the last to start is then a short one). Their kernels are apart, so none waits on
    another's compilation of the same kernel."""
    pending = sorted(names, key=list(SERVICES_BY_COST).index)
    running: dict[str, tuple[subprocess.Popen, float]] = {}
    failed = []
    while pending or running:
        while pending and len(running) < jobs:
            name = pending.pop(0)
            command = [sys.executable, "-m", "avs.cli", "warm-up", name]
            proc = subprocess.Popen(command, stdout=subprocess.DEVNULL)
            running[name] = proc, time.perf_counter()
        for name, (proc, t0) in list(running.items()):
            if proc.poll() is not None:
                del running[name]
                print(f"  {name}: {time.perf_counter() - t0:.1f} s", flush=True)
                if proc.returncode:
                    failed.append(name)
        time.sleep(0.1)
    if failed:
        print(f"the warm-up of {', '.join(failed)} failed (its error above)", file=sys.stderr)
    return 1 if failed else 0
