"""``avs realsense``: run the RealSense adapter (``avs realsense --help`` lists its settings)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "realsense",
        help="stream a RealSense D400 camera (or --playback a recording of one) as the robot's "
        "RGB-D camera and IMU",
        add_help=False,
    )
    parser.add_argument("args", nargs=argparse.REMAINDER, help="its own options (see its --help)")
    parser.set_defaults(func=lambda args: run(list(args.args)))


def run(rest: list[str]) -> int:
    """``avs realsense REST...``: everything after the command goes to the adapter's parser."""
    from services.adapters.realsense.__main__ import main

    return main(rest, prog="avs realsense")
