"""python -m services.perception — RGB-D frames in, scene observations out."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.perception.config import PerceptionSettings
from services.perception.node import PerceptionNode


def main(argv: list[str] | None = None) -> int:
    settings = PerceptionSettings.from_args(argv)
    return run_node(settings, lambda node: PerceptionNode(node, settings))


if __name__ == "__main__":
    sys.exit(main())
