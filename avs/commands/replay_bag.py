"""``avs replay-bag BAG --rgb TOPIC --depth TOPIC --camera-info TOPIC``: play the RGB-D images
of a ROS 1 (``.bag``) or ROS 2 (directory) bag onto ``sensors/rgbd/<camera>`` as RgbdFrames,
so perception and scene memory run on recordings of real robots. No ROS install is needed.

Colour and depth images are paired by the nearest header stamp (within --max-dt); depth may
be 16UC1 (mm) or 32FC1 (m), colour rgb8, bgr8, rgba8, bgra8 or mono8, registered to each
other (same size); compressed images too (CompressedImage: colour jpeg or png, depth
compressedDepth png). Intrinsics come from the CameraInfo. With --tf the camera pose is the
bag's tf tree (/tf and /tf_static) from its root, or --world-frame, to the CameraInfo's
frame_id (an optical frame: x right, y down, z forward), the world z up; without it the pose
is fixed (--pose). A TUM RGB-D benchmark bag:

  avs replay-bag rgbd_dataset_freiburg1_desk.bag --rgb /camera/rgb/image_color \\
      --depth /camera/depth/image --camera-info /camera/rgb/camera_info --tf
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from avs.commands._args import add_playback_arguments, non_negative_float
from avs.commands._transport import add_transport_arguments, connect, settings_from
from services.adapters.rosbag.bag import BagError, BagFrames, BagReplayConfig
from services.adapters.rosbag.convert import fixed_camera_pose
from services.adapters.rosbag.publish import Progress, publish_frames
from services.common.node import Node


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "replay-bag",
        help="play a ROS 1 / ROS 2 bag's RGB-D images as RgbdFrames",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("bag", type=Path, metavar="BAG", help="a ROS 1 .bag file or ROS 2 bag dir")
    topics = parser.add_argument_group("topics")
    topics.add_argument("--rgb", required=True, metavar="TOPIC", help="colour images (Image)")
    topics.add_argument("--depth", required=True, metavar="TOPIC", help="depth images (Image)")
    topics.add_argument(
        "--camera-info", required=True, metavar="TOPIC", help="the colour camera's CameraInfo"
    )
    pose = parser.add_argument_group("camera pose")
    pose.add_argument(
        "--tf",
        action="store_true",
        help="take the pose from the bag's /tf and /tf_static (else: --pose)",
    )
    pose.add_argument(
        "--world-frame",
        metavar="NAME",
        help="tf frame taken as the world (default: the root of the camera frame's tree)",
    )
    pose.add_argument(
        "--pose",
        type=float,
        nargs=6,
        metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
        help="fixed pose without --tf: the camera body frame (x forward, y left, z up) in the "
        "world, metres and degrees, pitch > 0 looking down (default: all 0)",
    )
    parser.add_argument(
        "--camera", default="head_rgbd", help="publish on sensors/rgbd/CAMERA (default head_rgbd)"
    )
    play = add_playback_arguments(parser, "bag")
    play.add_argument(
        "--max-dt",
        type=non_negative_float,
        default=0.02,
        metavar="S",
        help="largest stamp difference of a colour and a depth image to pair, s (default 0.02)",
    )
    play.add_argument(
        "--depth-scale",
        type=non_negative_float,
        default=None,
        metavar="M",
        help="metres per unit of 16UC1 depth (default 0.001: millimetres)",
    )
    play.add_argument(
        "--depth-range",
        type=non_negative_float,
        nargs=2,
        default=[0.0, 0.0],
        metavar=("MIN", "MAX"),
        help="the sensor's valid depth range the frames announce, m (default 0 0: unknown)",
    )
    add_transport_arguments(parser)
    parser.set_defaults(func=_replay)


def config_from(args: argparse.Namespace) -> BagReplayConfig:
    x, y, z, roll, pitch, yaw = args.pose or [0.0] * 6
    return BagReplayConfig(
        rgb=args.rgb,
        depth=args.depth,
        camera_info=args.camera_info,
        camera=args.camera,
        tf=args.tf,
        world_frame=args.world_frame,
        T_world_camera=fixed_camera_pose(
            x, y, z, math.radians(roll), math.radians(pitch), math.radians(yaw)
        ),
        max_dt=args.max_dt,
        depth_scale=args.depth_scale,
        depth_min=args.depth_range[0],
        depth_max=args.depth_range[1],
        start=args.start,
        limit=args.limit,
    )


def _replay(args: argparse.Namespace) -> int:
    if args.world_frame and not args.tf:
        raise SystemExit("avs replay-bag: --world-frame needs --tf")
    if args.pose and args.tf:
        raise SystemExit("avs replay-bag: --pose is the pose without --tf; give one of them")
    config = config_from(args)
    settings = settings_from(args)
    try:
        with BagFrames(args.bag, config) as frames:
            total = min(frames.expected, config.limit or frames.expected)
            with Node("replay_bag", settings, connect(settings)) as node:
                node.install_signal_handlers()
                progress = Progress(total)
                sent = publish_frames(node, frames, config.camera, args.rate, args.wait, progress)
                progress.close()
                node.spin(0.5)  # the last large frames may still be on their way via the router
            key = node.keys.rgbd(config.camera)
    except BagError as e:
        raise SystemExit(f"avs replay-bag: {e}") from None
    skipped = ", ".join(f"{n} {why}" for why, n in sorted(frames.skipped.items()))
    print(f"replay-bag: {sent} frames of {args.bag} on {key}"
          + (f"; skipped: {skipped}" if skipped else ""), file=sys.stderr)  # fmt: skip
    return 0
