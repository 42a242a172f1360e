"""``avs``: one command line for the whole stack. Every command has ``--help``."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from avs.commands import (
    echo,
    explore,
    explorer,
    fuse,
    gaze_experiment,
    grasp_experiment,
    perceive,
    realsense,
    record,
    replay_bag,
    replay_dataset,
    run,
    scene,
    schema,
    score,
    sim,
    status,
    up,
    view,
    warm_up,
)
from avs.commands._args import OneLineParser, explain
from services.common.log import setup_logging

COMMANDS = (
    run,
    explore,
    explorer,
    up,
    status,
    sim,
    realsense,
    scene,
    perceive,
    fuse,
    gaze_experiment,
    grasp_experiment,
    echo,
    record,
    view,
    replay_bag,
    replay_dataset,
    schema,
    score,
    warm_up,
)


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="avs",
        description="AVS, the Active Vision Stack: semantic scene understanding and "
        "next-best-view planning for humanoid robots, as Zenoh services.",
    )
    parser.add_argument(
        "--log-level",
        default="INFO",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        help="log level of this command (default INFO)",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in COMMANDS:
        command.register(sub)
    explain(parser)
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["sim"]:  # everything after 'sim' belongs to the sim's own parser
        setup_logging("avs", "sim")
        sys.exit(sim.run(argv[1:]))
    if argv[:1] == ["realsense"]:  # likewise the adapter's
        sys.exit(realsense.run(argv[1:]))
    args = build_parser().parse_args(argv)
    setup_logging("avs", args.command, args.log_level)
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        status = 130
    sys.exit(status or 0)


if __name__ == "__main__":
    main()
