"""The AVS recording format: what ``avs record`` writes and ``avs sim --replay`` plays.

A recording is a sequence of msgpack maps in one file (read it with ``msgpack.Unpacker``):

1. a header ``{"format": "avs-recording", "version": 1, "started": <unix time>,
   "keys": [<key expressions subscribed>]}``;
2. one record per received sample, in arrival order: ``{"t": <seconds since start>,
   "key": <the sample's key>, "payload": <the payload bytes, exactly as received>}``.

Payloads are kept raw, so a replay puts the very same bytes on the wire.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import msgpack

FORMAT = "avs-recording"
VERSION = 1


class RecordingError(ValueError):
    pass


@dataclass(frozen=True)
class Record:
    t: float
    key: str
    payload: bytes


class RecordingWriter:
    """Append records to a file; thread-safe (samples arrive on several threads)."""

    def __init__(self, path: Path, keys: list[str]) -> None:
        self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._lock = threading.Lock()
        self._t0 = time.monotonic()
        self.count = 0
        header = {"format": FORMAT, "version": VERSION, "started": time.time(), "keys": keys}
        self._file.write(msgpack.packb(header))

    def write(self, key: str, payload: bytes) -> None:
        with self._lock:
            record = {"t": time.monotonic() - self._t0, "key": key, "payload": payload}
            self._file.write(msgpack.packb(record, use_bin_type=True))
            self.count += 1

    def close(self) -> None:
        with self._lock:
            self._file.close()


def read_recording(path: Path) -> tuple[dict, Iterator[Record]]:
    """The header and an iterator over the records of a recording file."""
    f = open(path, "rb")  # noqa: SIM115 - closed when the iterator ends
    unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 30)
    try:
        header = next(unpacker)
    except (StopIteration, Exception) as e:
        f.close()
        raise RecordingError(f"{path}: not an AVS recording ({e or 'empty file'})") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        f.close()
        raise RecordingError(f"{path}: not an AVS recording (no {FORMAT!r} header)")
    if header.get("version") != VERSION:
        f.close()
        raise RecordingError(f"{path}: recording version {header.get('version')} is not {VERSION}")

    def records() -> Iterator[Record]:
        try:
            for item in unpacker:
                yield Record(float(item["t"]), str(item["key"]), bytes(item["payload"]))
        finally:
            f.close()

    return header, records()
