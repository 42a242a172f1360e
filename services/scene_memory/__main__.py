"""python -m services.scene_memory — what the robot knows of the scene, across views."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.scene_memory.config import SceneMemorySettings
from services.scene_memory.node import SceneMemoryNode


def main(argv: list[str] | None = None) -> int:
    settings = SceneMemorySettings.from_args(argv)
    return run_node(settings, lambda node: SceneMemoryNode(node, settings))


if __name__ == "__main__":
    sys.exit(main())
