"""``avs record KEYS... --out FILE.mcap``: write streams to an MCAP recording (one channel per
key, msgpack messages, each channel's JSON Schema; layout in services/common/recording.py) until
Ctrl-C, --duration or --count. ``avs sim --replay FILE.mcap`` plays it back.
``avs record --convert OLD --out NEW.mcap`` converts a recording of the old msgpack-stream
format."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

import zenoh

from avs.commands._transport import add_transport_arguments, connect, settings_from
from services.common.legacy_recording import convert_legacy
from services.common.recording import RecordingError, RecordingWriter


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "record",
        help="record streams to an MCAP file for replay",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "keys",
        nargs="*",
        metavar="KEY",
        help="key expressions; without a leading 'avs/' relative to avs/<robot>/",
    )
    parser.add_argument("--out", type=Path, required=True, help="MCAP file to write")
    parser.add_argument("--duration", type=float, default=0.0, help="stop after S seconds")
    parser.add_argument("--count", type=int, default=0, help="stop after N samples")
    parser.add_argument(
        "--max-queue-mb",
        type=float,
        default=256.0,
        help="samples waiting to be written beyond this are dropped and counted (default 256)",
    )
    parser.add_argument(
        "--convert", type=Path, metavar="OLD", help="convert an old-format recording instead"
    )
    add_transport_arguments(parser)
    parser.set_defaults(func=_main)


def _main(args: argparse.Namespace) -> int:
    if bool(args.convert) == bool(args.keys):
        print("avs record: give either KEY... or --convert OLD", file=sys.stderr)
        return 2
    if args.convert:
        try:
            n = convert_legacy(args.convert, args.out)
        except (OSError, RecordingError) as e:
            print(f"avs record: {e}", file=sys.stderr)
            return 1
        print(f"converted {n} messages from {args.convert} to {args.out}", file=sys.stderr)
        return 0
    return _record(args)


def _zenoh_time_ns(sample: zenoh.Sample) -> int | None:
    """The sample's Zenoh timestamp (NTP64 since the Unix epoch) in ns, if it has one."""
    if sample.timestamp is None:
        return None
    return sample.timestamp.get_time_as_ntp64().as_nanos()


def _record(args: argparse.Namespace) -> int:
    settings = settings_from(args)
    keys = [k if k.startswith("avs/") else f"avs/{settings.robot}/{k}" for k in args.keys]
    writer = RecordingWriter(args.out, keys, max_queued=int(args.max_queue_mb * (1 << 20)))
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())

    def on_sample(sample: zenoh.Sample) -> None:
        if done.is_set():
            return
        writer.write(str(sample.key_expr), sample.payload.to_bytes(), _zenoh_time_ns(sample))
        if args.count and writer.received >= args.count:
            done.set()

    session = connect(settings)
    subscribers = [session.declare_subscriber(k, on_sample) for k in keys]
    print(f"recording {', '.join(keys)} to {args.out}", file=sys.stderr, flush=True)
    t0 = time.monotonic()
    while not done.wait(0.5):
        if args.duration and time.monotonic() - t0 >= args.duration:
            break
        print(f"\r{writer.received} samples", end="", file=sys.stderr, flush=True)
    for s in subscribers:
        s.undeclare()
    session.close()
    writer.close()
    print(
        f"\rrecorded {writer.written} messages on {writer.file.channels} channels to {args.out}"
        + (f"; {writer.dropped} dropped (writing fell behind)" if writer.dropped else ""),
        file=sys.stderr,
    )
    return 0
