"""AVS recordings are MCAP files (https://mcap.dev): what ``avs record`` writes and ``avs sim
--replay`` plays (``services/common/playback.py`` reads them).

- one channel per key: the topic is the concrete key (``avs/armar6/sensors/imu``), the message
  encoding ``msgpack``; a key that carries several message types (``cmd/base``) has one channel
  per type;
- each channel's schema is its message's JSON Schema exactly as ``avs schema export`` writes it
  (schema encoding ``jsonschema``, schema name the message name); a payload that names no known
  message goes on a channel without a schema;
- message data are the payload bytes as received, so a replay puts the same bytes on the wire;
  ``log_time`` is when the recorder received the sample (ns since the Unix epoch, never going
  back), ``publish_time`` the sample's Zenoh timestamp where it has one (else ``log_time``),
  ``sequence`` counts per channel from 1;
- chunked (4 MiB) and zstd-compressed, with the summary, statistics and indexes;
- a metadata record ``avs``: ``{"format": "avs-recording", "version": "2", "keys": <JSON list of
  the key expressions subscribed>}``.
"""

from __future__ import annotations

import io
import json
import logging
import threading
import time
from collections import deque
from pathlib import Path
from typing import BinaryIO

import msgpack
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer

from schemas.base import REGISTRY
from schemas.export import json_schema_text

FORMAT = "avs-recording"
VERSION = "2"
METADATA = "avs"
CHUNK_SIZE = 4 << 20

log = logging.getLogger("avs.record")


class RecordingError(ValueError):
    """A file that cannot be read as an AVS recording; the text names the file and why."""


def schema_name(payload: bytes) -> str | None:
    """The registered message a payload names in its ``schema`` field (the first field of every
    AVS message, so this reads a few bytes), or None."""
    unpacker = msgpack.Unpacker(io.BytesIO(payload), raw=False, read_size=256)
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() == "schema":
                name = unpacker.unpack()
                return name if isinstance(name, str) and name in REGISTRY else None
            unpacker.skip()
    except (ValueError, msgpack.UnpackException, msgpack.OutOfData):
        return None
    return None


class RecordingFile:
    """An MCAP recording being written, one message at a time (not thread-safe: see
    ``RecordingWriter``)."""

    def __init__(self, path: Path, keys: list[str]) -> None:
        self.path = path
        self._file: BinaryIO = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._mcap = Writer(self._file, chunk_size=CHUNK_SIZE, compression=CompressionType.ZSTD)
        self._mcap.start(profile="")
        self._mcap.add_metadata(
            METADATA, {"format": FORMAT, "version": VERSION, "keys": json.dumps(keys)}
        )
        self._schemas: dict[str, int] = {}
        self._channels: dict[tuple[str, str | None], int] = {}
        self._sequence: dict[int, int] = {}
        self.count = 0

    def _channel(self, key: str, payload: bytes) -> int:
        name = schema_name(payload)
        channel = self._channels.get((key, name))
        if channel is None:
            schema_id = 0
            if name is not None:
                if name not in self._schemas:
                    data = json_schema_text(name).encode()
                    self._schemas[name] = self._mcap.register_schema(
                        name, SchemaEncoding.JSONSchema, data
                    )
                schema_id = self._schemas[name]
            else:
                log.warning("%s: a payload that names no AVS message; recorded without schema", key)
            channel = self._mcap.register_channel(key, MessageEncoding.MessagePack, schema_id)
            self._channels[(key, name)] = channel
        return channel

    def add(self, key: str, payload: bytes, log_time: int, publish_time: int) -> None:
        """Append one message; times in ns since the Unix epoch."""
        channel = self._channel(key, payload)
        sequence = self._sequence[channel] = self._sequence.get(channel, 0) + 1
        self._mcap.add_message(channel, log_time, payload, publish_time, sequence)
        self.count += 1

    @property
    def channels(self) -> int:
        return len(self._channels)

    def close(self) -> None:
        """Write the last chunk, the summary and the footer."""
        self._mcap.finish()
        self._file.close()


class RecordingWriter:
    """Records samples that arrive on several threads. ``write`` only stamps and queues (cheap
    enough for a Zenoh callback); a thread of its own compresses and writes. When more than
    ``max_queued`` bytes wait, a sample is dropped and counted in ``dropped``."""

    def __init__(self, path: Path, keys: list[str], max_queued: int = 256 << 20) -> None:
        self.file = RecordingFile(path, keys)
        self.max_queued = max_queued
        self.received = 0
        self.dropped = 0
        self._queue: deque[tuple[str, bytes, int, int]] = deque()
        self._queued = 0
        self._closing = False
        self._error: BaseException | None = None
        self._cond = threading.Condition()
        self._wall0, self._mono0 = time.time_ns(), time.monotonic_ns()
        self._thread = threading.Thread(target=self._run, name="recording-writer", daemon=True)
        self._thread.start()

    def write(self, key: str, payload: bytes, publish_time: int | None = None) -> bool:
        """Queue one sample, stamped now; False when it was dropped (queue full, or closed)."""
        with self._cond:
            if self._closing or (self._queue and self._queued + len(payload) > self.max_queued):
                self.dropped += 1
                return False
            log_time = self._wall0 + time.monotonic_ns() - self._mono0
            self._queue.append((key, payload, log_time, publish_time or log_time))
            self._queued += len(payload)
            self.received += 1
            self._cond.notify()
        return True

    @property
    def written(self) -> int:
        return self.file.count

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue:
                    return
                key, payload, log_time, publish_time = self._queue.popleft()
                self._queued -= len(payload)
            try:
                self.file.add(key, payload, log_time, publish_time)
            except BaseException as e:  # a full disk: stop taking samples, close() raises it
                with self._cond:
                    self._error, self._closing = e, True
                    self.dropped += len(self._queue) + 1
                    self._queue.clear()
                return

    def close(self) -> None:
        """Write what is queued, then finish the file; raises what failed while writing."""
        with self._cond:
            self._closing = True
            self._cond.notify()
        self._thread.join()
        self.file.close()
        if self._error is not None:
            raise self._error
