"""``avs scene generate --seed N --out FILE``: a random table-top scene (table, 3-8 objects in
stacks, bridges, hidden and touching arrangements, the robot's start around it), settled by
physics. ``avs scene validate FILE``: every problem of a scene file, one line each."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("scene", help="generate and validate scene files", description=__doc__)
    actions = parser.add_subparsers(dest="action", required=True, metavar="ACTION")
    generate = actions.add_parser(
        "generate",
        help="write a random table-top scene (the same seed gives the same file)",
    )
    generate.add_argument("--seed", type=int, required=True, help="random seed")
    generate.add_argument("--out", type=Path, required=True, metavar="FILE", help="MJCF file")
    generate.add_argument(
        "--shelf", action="store_true",
        help="an open shelf (two boards, side panels) with a stack on its upper board, not a table",
    )  # fmt: skip
    generate.set_defaults(func=_generate)
    validate = actions.add_parser(
        "validate",
        help="print every problem of a scene file (exit 1 if any, 2 if it does not load)",
    )
    validate.add_argument("file", type=Path, metavar="FILE", help="the MJCF scene file")
    validate.add_argument("--robot", default="armar6", help="robot at robot_start")
    validate.set_defaults(func=_validate)


def _generate(args: argparse.Namespace) -> int:
    from services.sim.generate import GenerationError, generate

    if args.out.suffix.lower() != ".xml":
        # MuJoCo tells an MJCF file by its extension: any other name would be written, then
        # refused by every command that loads it
        print(f"avs scene generate: --out {args.out} must end in .xml (an MJCF file)",
              file=sys.stderr)  # fmt: skip
        return 2
    try:
        scene = generate(args.seed, shelf=args.shelf)
    except GenerationError as e:
        print(f"avs scene generate: {e}", file=sys.stderr)
        return 1
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(scene.text)
    arrangements = "; ".join(str(a) for a in scene.arrangements)
    print(f"{args.out}: seed {args.seed}, {len(scene.objects)} objects: {arrangements}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    from services.sim.robots import ROBOTS
    from services.sim.validate import check_scene

    if args.robot not in ROBOTS:
        print(
            f"avs scene validate: no robot {args.robot!r} (have {sorted(ROBOTS)})", file=sys.stderr
        )
        return 2
    result = check_scene(args.file, args.robot)
    if not result.loads:
        print(result.problems[0], file=sys.stderr)
        return 2
    for problem in result.problems:
        print(problem)
    if result.problems:
        return 1
    print(f"{args.file}: ok")
    return 0
