"""python -m services.gaze — ego-sphere view selection and gaze stabilisation (thesis Ch. 5)."""

from __future__ import annotations

import os
import sys

from services.common.main import run_node
from services.common.realtime import prioritise, threads
from services.gaze.config import GazeSettings
from services.gaze.node import GazeNode


def pin(cpus: list[int]) -> None:
    """This process on ``cpus``: every thread so far (imports start some, e.g. BLAS's) and,
    by inheritance, every thread started from now on."""
    for tid in threads():
        os.sched_setaffinity(tid, cpus)


def main(argv: list[str] | None = None) -> int:
    settings = GazeSettings.from_args(argv)
    if settings.cpus:  # before Zenoh's threads and ours start: they inherit it
        pin(settings.cpus)

    def build(node):
        if settings.realtime:  # every thread so far (Zenoh's too) and every later one
            prioritise("the gaze control loop")
        return GazeNode(node, settings)

    return run_node(settings, build)


if __name__ == "__main__":
    sys.exit(main())
