"""Reading an AVS recording (the MCAP layout in ``services/common/recording.py``) for replay:
its AVS channels (msgpack on ``avs/...`` topics) in log-time order, with their timing."""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from mcap.exceptions import McapError
from mcap.reader import SeekingReader, make_reader
from mcap.well_known import MessageEncoding

from services.common.legacy_recording import is_legacy_recording
from services.common.recording import METADATA, RecordingError

_BROKEN = (McapError, EOFError, OSError, struct.error, ValueError, KeyError)
MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class Record:
    t: float  # seconds since the recording's first message
    key: str
    payload: bytes


@dataclass
class Recording:
    """An opened recording: what it holds, and its records (read once, lazily)."""

    path: Path
    keys: list[str]  # the key expressions recorded (the topics, when the file does not say)
    counts: dict[str, int]  # messages per AVS topic
    records: Iterator[Record]

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


def _is_avs(channel) -> bool:
    return channel.message_encoding == MessageEncoding.MessagePack and channel.topic.startswith(
        "avs/"
    )


def open_recording(path: Path) -> Recording:
    """Open an MCAP recording for replay; a ``RecordingError`` says why a file cannot be."""
    if not path.is_file():
        raise RecordingError(f"recording {path}: no such file")
    with open(path, "rb") as probe:
        magic = probe.read(len(MAGIC))
    if magic != MAGIC:
        if is_legacy_recording(path):
            raise RecordingError(
                f"{path}: an AVS recording of the old msgpack-stream format; convert it with "
                f"'avs record --convert {path} --out NEW.mcap'"
            )
        raise RecordingError(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
    f: BinaryIO = open(path, "rb")  # noqa: SIM115 - closed when the records end
    try:
        reader = make_reader(f)
        summary = reader.get_summary()
    except _BROKEN as e:
        f.close()
        why = str(e) or type(e).__name__
        raise RecordingError(
            f"{path}: an MCAP file cut short or damaged (was its recorder killed?): {why}"
        ) from None
    if summary is None:
        f.close()
        raise RecordingError(f"{path}: an MCAP file without summary (was its recorder killed?)")
    channels = {cid: c for cid, c in summary.channels.items() if _is_avs(c)}
    if not channels:
        f.close()
        found = ", ".join(
            f"{c.topic} ({c.message_encoding or 'no encoding'})" for c in summary.channels.values()
        )
        raise RecordingError(
            f"{path}: no AVS channels (msgpack messages on avs/... topics); "
            f"it has {found or 'no channels at all (nothing was recorded)'}"
        )
    stats = summary.statistics
    counts: dict[str, int] = {}
    for cid, c in channels.items():
        n = stats.channel_message_counts.get(cid, 0) if stats else 0
        counts[c.topic] = counts.get(c.topic, 0) + n
    keys = sorted(counts)
    for m in reader.iter_metadata():
        if m.name == METADATA and "keys" in m.metadata:
            keys = list(json.loads(m.metadata["keys"]))
    return Recording(path, keys, counts, _records(path, f, reader, sorted(counts)))


def _records(path: Path, f: BinaryIO, reader: SeekingReader, topics: list[str]) -> Iterator[Record]:
    n, start = 0, None
    try:
        for _, channel, message in reader.iter_messages(topics=topics, log_time_order=True):
            start = message.log_time if start is None else start
            yield Record((message.log_time - start) * 1e-9, channel.topic, bytes(message.data))
            n += 1
    except _BROKEN as e:
        raise RecordingError(f"{path}: unreadable after {n} messages ({e})") from None
    finally:
        f.close()
