"""``avs replay-dataset DIR``: play a recorded RGB-D dataset onto ``sensors/rgbd/<camera>`` as
RgbdFrames, as ``avs replay-bag`` does for bags: TUM RGB-D folders (rgb.txt, depth.txt,
groundtruth.txt), the 7-Scenes / 3DMatch layout (frame-NNNNNN.color.jpg, .depth.png, .pose.txt,
camera-intrinsics.txt) and plain folders of colour and depth images (--intrinsics,
--depth-scale). Poses come from the dataset where it has them, else --pose.

--up puts the world's z up and the floor at z = 0: ``auto`` finds the level planes of a few
frames (the floor, table tops) and keeps the dataset's own frame where its z is up already;
``given`` keeps the dataset's frame. What it chose is printed and written to --up-file.

--drift MM,DEG gives the poses an odometry-like drift, to try view registration on them: the
k-th played frame's pose is turned by k·DEG degrees of yaw about the vertical through the first
frame's camera and moved k·MM millimetres along the world's +x (after --up).

  avs up --services perception,scene_memory &
  avs replay-dataset ../shared/data/real/redkitchen-a --up auto
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from avs.commands._args import add_playback_arguments, non_negative_float, non_negative_int
from avs.commands._transport import add_transport_arguments, connect, settings_from


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "replay-dataset",
        help="play a recorded RGB-D dataset (TUM, 7-Scenes, a folder) as RgbdFrames",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("root", type=Path, metavar="DIR", help="the dataset's folder")
    parser.add_argument("--format", choices=("tum", "7scenes", "folder"),
                        help="its layout (default: detected)")  # fmt: skip
    parser.add_argument("--intrinsics", metavar="FX,FY,CX,CY",
                        help="the depth camera's intrinsics, where the dataset has none or "
                        "they are wrong")  # fmt: skip
    parser.add_argument("--depth-scale", type=non_negative_float, default=None, metavar="M",
                        help="metres per depth unit (default: the layout's; TUM 1/5000, "
                        "7-Scenes and folders 0.001)")  # fmt: skip
    parser.add_argument("--up", choices=("auto", "given"), default="auto",
                        help="z up and the floor at 0: found from the level planes (auto, the "
                        "default), or the dataset's frame as it is (given)")  # fmt: skip
    parser.add_argument("--up-file", type=Path, default=None, metavar="FILE",
                        help="write the chosen rotation, floor and planes as JSON")  # fmt: skip
    parser.add_argument("--drift", type=_drift, default=None, metavar="MM,DEG",
                        help="add k·MM mm along +x and k·DEG° of yaw (about the first camera's "
                        "vertical) to the k-th frame's pose: an odometry-like drift")  # fmt: skip
    parser.add_argument("--pose", type=float, nargs=6, default=None,
                        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
                        help="the camera body's fixed pose where the dataset has no poses "
                        "(metres, degrees; pitch > 0 looks down)")  # fmt: skip
    parser.add_argument(
        "--no-colour",
        action="store_true",
        help="depth only (colour not registered to depth, or of another size)",
    )
    parser.add_argument("--camera", default="head_rgbd",
                        help="publish on sensors/rgbd/CAMERA (default head_rgbd)")  # fmt: skip
    add_playback_arguments(parser, "recording").add_argument(
        "--every", type=non_negative_int, default=1, metavar="N",
        help="every N-th frame (default 1)",
    )  # fmt: skip
    add_transport_arguments(parser)
    parser.set_defaults(func=_replay)


def _drift(text: str):
    from services.adapters.dataset.drift import Drift

    try:
        return Drift.parse(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def _intrinsics(text: str | None):
    from services.adapters.dataset.formats import Intrinsics

    if text is None:
        return None
    try:
        fx, fy, cx, cy = (float(v) for v in text.split(","))
    except ValueError:
        raise SystemExit(
            f"avs replay-dataset: --intrinsics wants FX,FY,CX,CY, not {text!r}"
        ) from None
    return Intrinsics(0, 0, fx, fy, cx, cy)


def prepare(args: argparse.Namespace):
    """The frames to play and what --up chose (None with ``given``)."""
    from services.adapters.camera import fixed_camera_pose
    from services.adapters.dataset.formats import read
    from services.adapters.dataset.frames import DatasetFrames
    from services.adapters.dataset.gravity import level_frame

    rec = read(args.root, args.format, _intrinsics(args.intrinsics), args.depth_scale)
    x, y, z, roll, pitch, yaw = args.pose or [0.0] * 6
    frames = DatasetFrames(
        rec, camera=args.camera,
        T_fixed=fixed_camera_pose(x, y, z, math.radians(roll), math.radians(pitch),
                                  math.radians(yaw)),
        start=args.start, every=args.every or 1, limit=args.limit, colour=not args.no_colour,
        drift=args.drift,
    )  # fmt: skip
    up = None
    if args.up == "auto":
        up = level_frame(frames)
        frames.T_up = up.T_up
    return frames, up


def _replay(args: argparse.Namespace) -> int:
    from services.adapters.dataset.formats import DatasetError
    from services.adapters.rosbag.publish import Progress, publish_frames
    from services.common.node import Node

    try:
        frames, up = prepare(args)
    except DatasetError as e:
        raise SystemExit(f"avs replay-dataset: {e}") from None
    rec = frames.recording
    print(f"replay-dataset: {args.root} ({rec.format}): {len(frames.indices())} of {len(rec)} "
          f"frames, {'poses from the dataset' if rec.poses is not None else 'a fixed pose'}"
          + (f", drift {args.drift.mm:g} mm and {args.drift.deg:g}° a frame" if args.drift else ""),
          file=sys.stderr)  # fmt: skip
    if up is not None:
        print(f"replay-dataset: up: {up.detail}", file=sys.stderr)
        if args.up_file is not None:
            args.up_file.write_text(json.dumps(up.to_json(), indent=1))
    settings = settings_from(args)
    try:
        with Node("replay_dataset", settings, connect(settings)) as node:
            node.install_signal_handlers()
            progress = Progress(len(frames.indices()), label="replay-dataset")
            sent = publish_frames(node, frames, args.camera, args.rate, args.wait, progress)
            progress.close()
            node.spin(0.5)  # the last large frames may still be on their way via the router
            key = node.keys.rgbd(args.camera)
    except DatasetError as e:
        raise SystemExit(f"avs replay-dataset: {e}") from None
    print(f"replay-dataset: {sent} frames of {args.root} on {key}", file=sys.stderr)
    return 0
