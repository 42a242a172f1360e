"""The first AVS recording format (before MCAP), kept only to convert old files:
``avs record --convert OLD --out NEW.mcap``.

It was a sequence of msgpack maps: a header ``{"format": "avs-recording", "version": 1,
"started": <unix time>, "keys": [...]}``, then per sample ``{"t": <seconds since start>, "key",
"payload": <bytes>}``.
"""

from __future__ import annotations

from pathlib import Path

import msgpack

from services.common.recording import FORMAT, RecordingError, RecordingFile


def _header(unpacker: msgpack.Unpacker) -> dict | None:
    try:
        header = next(unpacker)
    except Exception:  # anything msgpack cannot read is not this format
        return None
    ok = isinstance(header, dict) and header.get("format") == FORMAT and header.get("version") == 1
    return header if ok else None


def is_legacy_recording(path: Path) -> bool:
    """Whether ``path`` starts with the old format's header."""
    with open(path, "rb") as f:
        return _header(msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 20)) is not None


def convert_legacy(old: Path, new: Path) -> int:
    """Write the old-format recording ``old`` as the MCAP recording ``new``, with the same keys,
    payloads, order and timing; returns the number of messages."""
    with open(old, "rb") as f:
        unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 30)
        header = _header(unpacker)
        if header is None:
            raise RecordingError(f"{old}: not an AVS recording of the old format")
        started = int(float(header.get("started", 0.0)) * 1e9)
        out = RecordingFile(new, [str(k) for k in header.get("keys", [])])
        try:
            last = started
            for item in unpacker:
                # the old times came from a monotonic clock: never let them go back
                last = max(last, started + int(float(item["t"]) * 1e9))
                out.add(str(item["key"]), bytes(item["payload"]), last, last)
        except (ValueError, KeyError, TypeError, msgpack.UnpackException) as e:
            raise RecordingError(f"{old}: broken after {out.count} records ({e})") from None
        finally:
            out.close()
    return out.count
