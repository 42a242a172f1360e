"""``avs explorer start|pause|resume|stop|status``: steer a running explorer (``explore/control``;
under the access control only the ``operator`` identity may). Prints the explorer's status
after the request as one line (``--json``: the ExploreStatus); the exit status is 1 when the
explorer refused (its error on stderr) or nothing answered."""

from __future__ import annotations

import argparse
import json
import sys

from avs.commands._transport import add_transport_arguments, connect, settings_from


def _xyz(text: str) -> list[float]:
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: expected x,y,z")
    return v


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("explorer", help="start, pause, resume or stop the running explorer",
                       description=__doc__)  # fmt: skip
    p.add_argument(
        "op", choices=["start", "pause", "resume", "stop", "status"],
        help="what to ask the running explorer",
    )  # fmt: skip
    p.add_argument("--views", type=int, default=0, help="start: views at most (0: its setting)")
    p.add_argument("--roi-min", type=_xyz, metavar="X,Y,Z", help="start: the roi's low corner")
    p.add_argument("--roi-max", type=_xyz, metavar="X,Y,Z", help="start: … and its high one")
    p.add_argument("--json", action="store_true", help="the status as JSON")
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the answer")
    add_transport_arguments(p)
    p.set_defaults(func=_explorer)


def status_line(s) -> str:
    why = ": ".join(w for w in (s.reason, s.detail) if w)
    return (f"episode {s.episode}: {s.phase}, view {s.view}/{s.views}"
            + (f", {why}" if why else ""))  # fmt: skip


def _explorer(args: argparse.Namespace) -> int:
    import numpy as np

    from avs.commands.echo import to_jsonable
    from schemas import CodecError, ExploreControl, ExploreStatus, Keys, decode, encode

    if (args.roi_min is None) != (args.roi_max is None):
        raise SystemExit("avs explorer: --roi-min and --roi-max come together")
    try:
        request = ExploreControl(
            op=args.op, views=args.views,
            roi_min=np.array(args.roi_min) if args.roi_min else None,
            roi_max=np.array(args.roi_max) if args.roi_max else None,
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(f"avs explorer: {e}") from None
    settings = settings_from(args, instance="explorer-cli")
    keys = Keys(settings.robot)
    with connect(settings) as session:
        replies = list(session.get(keys.explore_control(), payload=encode(request),
                                   timeout=args.timeout))  # fmt: skip
    status = None
    for reply in replies:
        if reply.ok is not None:
            try:
                status = decode(reply.ok.payload.to_bytes(), ExploreStatus)
            except CodecError as e:
                print(f"avs explorer: an answer that is not a status: {e}", file=sys.stderr)
    if status is None:
        print(f"avs explorer: no explorer answered on {keys.explore_control()} (not running, "
              "or this identity may not control it)", file=sys.stderr)  # fmt: skip
        return 1
    print(json.dumps(to_jsonable(status.model_dump())) if args.json else status_line(status))
    if not status.ok:
        print(f"avs explorer: {status.error}", file=sys.stderr)
        return 1
    return 0
