"""``avs record KEYS... --out FILE``: write streams to a recording (format in
services/common/recording.py) until Ctrl-C, --duration or --count. ``avs sim --replay FILE``
plays it back."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

from avs.commands._transport import add_transport_arguments, connect, settings_from
from services.common.recording import RecordingWriter


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "record",
        help="record streams to a file for replay",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "keys",
        nargs="+",
        metavar="KEY",
        help="key expressions; without a leading 'avs/' relative to avs/<robot>/",
    )
    parser.add_argument("--out", type=Path, required=True, help="recording file to write")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds")
    parser.add_argument("--count", type=int, default=0, help="stop after N samples")
    add_transport_arguments(parser)
    parser.set_defaults(func=_record)


def _record(args: argparse.Namespace) -> int:
    settings = settings_from(args)
    keys = [k if k.startswith("avs/") else f"avs/{settings.robot}/{k}" for k in args.keys]
    writer = RecordingWriter(args.out, keys)
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())

    def on_sample(sample: zenoh.Sample) -> None:
        if done.is_set():
            return
        writer.write(str(sample.key_expr), sample.payload.to_bytes())
        if args.count and writer.count >= args.count:
            done.set()

    session = connect(settings)
    subscribers = [session.declare_subscriber(k, on_sample) for k in keys]
    print(f"recording {', '.join(keys)} to {args.out}", file=sys.stderr, flush=True)
    t0 = time.monotonic()
    while not done.wait(0.5):
        if args.duration and time.monotonic() - t0 >= args.duration:
            break
        print(f"\r{writer.count} samples", end="", file=sys.stderr, flush=True)
    for s in subscribers:
        s.undeclare()
    session.close()
    writer.close()
    print(f"\rrecorded {writer.count} samples to {args.out}", file=sys.stderr)
    return 0
