"""python -m services.adapters.realsense — a RealSense camera (or a recording) as AVS sensors."""

from __future__ import annotations

import sys

from services.adapters.realsense.config import RealsenseSettings
from services.adapters.realsense.device import RealsenseError, import_rs
from services.common.main import run_node

PROG = "python -m services.adapters.realsense"


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    settings = RealsenseSettings.from_args(argv, prog=prog or PROG)
    name = prog or PROG
    try:
        rs = import_rs()
        from services.adapters.realsense.node import RealsenseNode

        return run_node(settings, lambda node: RealsenseNode(node, settings, rs))
    except RealsenseError as e:
        print(f"{name}: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
