"""``avs echo KEY``: print every message on KEY as one JSON line — the reference subscriber.

Arrays with at most ``--max-array`` elements are printed in full, larger ones as dtype, shape
and min / max / mean. Payloads that are not valid messages are counted and reported once per
reason on stderr; they never stop the command.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import threading
from typing import Any

import numpy as np
from pydantic import BaseModel

from avs.commands._transport import add_transport_arguments, connect, settings_from
from schemas.base import Message
from services.common.node import Node


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "echo",
        help="print the messages on a key expression as JSON lines",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "key",
        metavar="KEY",
        help="key expression; without a leading 'avs/' it is relative to avs/<robot>/ "
        "(e.g. sensors/imu, perception/**)",
    )
    parser.add_argument("--count", type=int, default=0, help="exit after N messages (0: never)")
    parser.add_argument(
        "--timeout", type=float, default=0.0, help="exit after S seconds (0: never)"
    )
    parser.add_argument(
        "--max-array",
        type=int,
        default=16,
        help="print arrays up to this many elements in full (default 16)",
    )
    add_transport_arguments(parser)
    parser.set_defaults(func=_echo)


def _number(x: float) -> Any:
    if math.isfinite(x):
        return x
    return "NaN" if math.isnan(x) else ("Infinity" if x > 0 else "-Infinity")


def to_jsonable(value: Any, max_array: int = 16) -> Any:
    """A JSON-ready view of a message or any of its parts."""
    if isinstance(value, BaseModel):
        body = {k: to_jsonable(getattr(value, k), max_array) for k in type(value).model_fields}
        if isinstance(value, Message):
            body = {"schema": value.SCHEMA, "version": value.VERSION, **body}
        return body
    if isinstance(value, np.ndarray):
        if value.size <= max_array:
            return to_jsonable(value.tolist(), max_array)
        out: dict[str, Any] = {"dtype": value.dtype.name, "shape": list(value.shape)}
        if value.dtype.kind in "biuf" and value.size:
            finite = value[np.isfinite(value)] if value.dtype.kind == "f" else value
            if finite.size:
                out.update(
                    min=_number(float(finite.min())),
                    max=_number(float(finite.max())),
                    mean=_number(float(finite.mean())),
                )
        return out
    if isinstance(value, float):
        return _number(value)
    if isinstance(value, dict):
        return {str(k): to_jsonable(v, max_array) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [to_jsonable(v, max_array) for v in value]
    return value


def _echo(args: argparse.Namespace) -> int:
    settings = settings_from(args)
    key = args.key if args.key.startswith("avs/") else f"avs/{settings.robot}/{args.key}"
    done = threading.Event()
    printed = 0
    closed = False  # the reader closed the pipe (``avs echo KEY | head``)
    lock = threading.Lock()

    with Node("echo", settings, connect(settings), announce=False) as node:
        node.install_signal_handlers()

        def show(message: Message, sample_key: str) -> None:
            nonlocal printed, closed
            with lock:
                if done.is_set():
                    return
                body = {"key": sample_key, "message": to_jsonable(message, args.max_array)}
                line = json.dumps(body, allow_nan=False)
                try:
                    sys.stdout.write(line + "\n")
                    sys.stdout.flush()
                except (BrokenPipeError, ValueError):  # the reader is gone: stop, quietly
                    closed = True
                    done.set()
                    node.stop()
                    return
                printed += 1
                if args.count and printed >= args.count:
                    done.set()
                    node.stop()

        node.subscribe(key, Message, show, name="echo", with_key=True)
        node.announce()
        node.spin(args.timeout or None)
    if closed:
        # what Python would flush at exit goes nowhere, instead of a BrokenPipeError warning
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    invalid = invalid_payloads(node.metrics.snapshot().dropped)
    if invalid:
        reasons = ", ".join(f"{reason}={n}" for reason, n in sorted(invalid.items()))
        print(f"avs echo: {sum(invalid.values())} payloads on {key} were not valid messages "
              f"and were not printed ({reasons})", file=sys.stderr)  # fmt: skip
    return 0


def invalid_payloads(dropped: dict[str, int]) -> dict[str, int]:
    """The drops that were payloads failing to decode (a codec's fault: ``not_msgpack``,
    ``schema``, …), not this command's own trouble (a handler error)."""
    return {r: n for r, n in dropped.items() if n and not r.startswith("handler_error")}
