"""python -m services.nbv — the next-best-view planner (thesis Ch. 4)."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.nbv.config import NbvSettings
from services.nbv.node import NbvNode


def main(argv: list[str] | None = None) -> int:
    settings = NbvSettings.from_args(argv)
    return run_node(settings, lambda node: NbvNode(node, settings))


if __name__ == "__main__":
    sys.exit(main())
