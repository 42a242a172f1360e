"""python -m services.gaze — ego-sphere view selection and gaze stabilisation (thesis Ch. 5)."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.gaze.config import GazeSettings
from services.gaze.node import GazeNode


def main(argv: list[str] | None = None) -> int:
    settings = GazeSettings.from_args(argv)
    return run_node(settings, lambda node: GazeNode(node, settings))


if __name__ == "__main__":
    sys.exit(main())
