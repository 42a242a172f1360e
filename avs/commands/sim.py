"""``avs sim``: run the sim service (``avs sim --help`` lists its settings), or
``avs sim ground-truth --scene S --json`` to print a scene's ground truth without Zenoh."""

from __future__ import annotations

import argparse
import json
import sys


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "sim",
        help="run the simulated robot (or --replay a recording); "
        "'avs sim ground-truth' prints a scene's ground truth",
        add_help=False,
    )
    parser.add_argument("args", nargs=argparse.REMAINDER, help="its own options (see its --help)")
    parser.set_defaults(func=_sim)


def _ground_truth_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="avs sim ground-truth",
        description="Objects and support graph of a scene by the thesis's definition (remove "
        "A, simulate 0.5 s: B moved > 1 cm or turned > 2°), printed as JSON.",
    )
    p.add_argument("--scene", default="tabletop_occluded", help="built-in name or MJCF file")
    p.add_argument("--robot", default="armar6", help="robot placed at robot_start")
    p.add_argument("--json", action="store_true", help="print JSON (the only output format)")
    return p


def _sim(args: argparse.Namespace) -> int:
    return run(list(args.args))


def run(rest: list[str]) -> int:
    """``avs sim REST...``: the ground-truth sub-command, or the sim service itself."""
    if rest and rest[0] == "ground-truth":
        return _ground_truth(_ground_truth_parser().parse_args(rest[1:]))
    from services.sim.__main__ import main

    return main(rest, prog="avs sim")


def _ground_truth(args: argparse.Namespace) -> int:
    from services.sim import ground_truth
    from services.sim.robots import ROBOTS
    from services.sim.scene import SceneError
    from services.sim.world import World

    if args.robot not in ROBOTS:
        print(
            f"avs sim: unknown robot {args.robot!r} (known: {', '.join(ROBOTS)})", file=sys.stderr
        )
        return 2
    try:
        world = World(args.scene, ROBOTS[args.robot])
    except SceneError as e:
        print(f"avs sim: {e}", file=sys.stderr)
        return 2
    edges, closure = ground_truth.support_graph(world.model, world.data, world.info)
    out = {
        "scene": world.info.name,
        "objects": [
            {
                "name": o.name,
                "kind": o.kind,
                "pose": o.pose.tolist(),
                "size": o.size.tolist(),
                "static": o.static,
            }
            for o in ground_truth.objects(world)
        ],
        "support_edges": [list(e) for e in edges],
        "support_closure": [list(e) for e in closure],
    }
    print(json.dumps(out, indent=2))
    return 0
