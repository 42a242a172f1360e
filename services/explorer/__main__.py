"""python -m services.explorer — the exploration loop (thesis 4.5)."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.explorer.config import ExplorerSettings
from services.explorer.node import ExplorerNode


def main(argv: list[str] | None = None) -> int:
    settings = ExplorerSettings.from_args(argv)
    return run_node(settings, lambda node: ExplorerNode(node, settings))


if __name__ == "__main__":
    sys.exit(main())
