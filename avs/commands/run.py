"""``avs run``: the main job — one whole exploration episode on ``tabletop_occluded`` with the
defaults (utility strategy, equidistant sampling, sg fusion, at most 10 views), every service
a local process on a loopback Zenoh router. It prints a progress bar and a short summary and
writes the metrics, plots and report.html under ``--out`` (default runs/explore), every
service's log in ``OUT/logs/<service>.log`` (``--verbose``: live on the console too)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from avs.commands._args import add_console_arguments, positive_int, scene_help
from avs.commands.explore import episode, summary, write_outputs
from avs.console import log_to


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "run",
        help="the main job: a whole exploration episode",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--scene", default="tabletop_occluded", help=scene_help())
    parser.add_argument("--views", type=positive_int, default=10, help="at most this many views")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sim's noise and sampling")
    parser.add_argument(
        "--noise", choices=["on", "off"], default="on",
        help="the robot's sensor models (depth noise, odometry drift, gyro, encoders; the scene "
        "memory registers the views) or the simulator's truth",
    )  # fmt: skip
    parser.add_argument(
        "--out", type=Path, default=Path("runs/explore"),
        help="where the metrics, plots and report.html go",
    )  # fmt: skip
    add_console_arguments(parser)
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from experiments.episode import EpisodeConfig

    log_to(args.out / "logs", "run")
    on = args.noise == "on"
    config = EpisodeConfig(scene=args.scene, views=args.views, seed=args.seed, out=args.out,
                           noise=on, registration=on)  # fmt: skip
    try:
        result = episode(config, "episode", args.verbose)
    except (RuntimeError, TimeoutError) as e:
        print(f"avs run: {e}", file=sys.stderr)
        return 1
    (args.out / "metrics.json").write_text(json.dumps(result, indent=2))
    page = write_outputs(args.out, {"utility": [result]}, f"{args.scene}: utility")
    summary(result)
    print(f"metrics, plots and {page} in {args.out}; logs in {args.out / 'logs'}")
    return 0
