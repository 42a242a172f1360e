"""python -m services.sim — the simulated robot (or, with --replay, a recording of one)."""

from __future__ import annotations

import sys

from services.common.main import run_node
from services.common.realtime import prioritise
from services.sim.config import SimSettings
from services.sim.robots import ROBOTS
from services.sim.scene import SceneError


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    settings = SimSettings.from_args(argv, prog=prog)
    if settings.replay is not None:
        from services.sim.replay import ReplayNode, open_replay

        try:
            recording = open_replay(settings.replay)
        except ValueError as e:
            print(f"avs sim: {e}", file=sys.stderr)
            return 2
        return run_node(settings, lambda node: ReplayNode(node, settings, recording))

    from services.sim.node import SimNode
    from services.sim.world import World

    if settings.robot not in ROBOTS:
        print(
            f"avs sim: unknown robot {settings.robot!r} (known: {', '.join(ROBOTS)})",
            file=sys.stderr,
        )
        return 2
    try:
        world = World(
            settings.scene, ROBOTS[settings.robot], timestep=settings.timestep, sleep=settings.sleep
        )
    except SceneError as e:
        print(f"avs sim: {e}", file=sys.stderr)
        return 2

    def build(node):
        if settings.realtime and not settings.lockstep:
            prioritise("the sim's physics and IMU")
        return SimNode(node, settings, world)

    return run_node(settings, build)


if __name__ == "__main__":
    sys.exit(main())
