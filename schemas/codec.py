"""msgpack codec of every AVS message.

A message on the wire is one msgpack map: ``{"schema": name, "version": n, <fields>}``. Nested
models are maps, numpy arrays are ``{"dtype", "shape", "bytes"}`` maps (see ``schemas.arrays``).
``decode`` refuses anything else with a ``CodecError`` — never another exception — whose
``kind`` says why (for drop counters) and whose text says where.
"""

from __future__ import annotations

import threading
from typing import Any, TypeVar

import msgpack
import numpy as np
from pydantic import BaseModel, ValidationError

from schemas.arrays import _LITTLE, WIRE_CONTEXT, array_to_wire, wire_dtype_name
from schemas.base import REGISTRY, Message

M = TypeVar("M", bound=Message)

#: The reasons a payload is refused, as ``CodecError.kind``.
ERROR_KINDS = (
    "malformed",  # not msgpack, or trailing bytes
    "not_a_message",  # msgpack, but not a map with schema and version
    "unknown_schema",
    "wrong_version",
    "unexpected_schema",  # a valid message of another type than the receiver expects
    "invalid",  # fields fail validation: missing, unknown, wrong type, bad array
)


class CodecError(ValueError):
    """A payload that is not a valid AVS message."""

    def __init__(self, kind: str, message: str, schema: str | None = None) -> None:
        super().__init__(message)
        self.kind = kind
        self.schema = schema


def _header(small: int, fix_limit: int, code16: int, code32: int, n: int) -> bytes:
    if n < fix_limit:
        return bytes((small | n,))
    if n < 0x10000:
        return bytes((code16,)) + n.to_bytes(2, "big")
    return bytes((code32,)) + n.to_bytes(4, "big")


def _bin_header(n: int) -> bytes:
    if n < 0x100:
        return b"\xc4" + n.to_bytes(1, "big")
    if n < 0x10000:
        return b"\xc5" + n.to_bytes(2, "big")
    return b"\xc6" + n.to_bytes(4, "big")


_local = threading.local()


def _packb(value: Any) -> bytes:
    """msgpack of a scalar or small value, with a packer per thread (a Packer is not
    thread-safe, and building one per call costs more than the packing)."""
    packer = getattr(_local, "packer", None)
    if packer is None:
        packer = _local.packer = msgpack.Packer(use_bin_type=True)
    return packer.pack(value)


_ARRAY_KEYS = [_packb("dtype"), None, _packb("shape"), None, _packb("bytes")]

#: msgpack of everything in an array's map before its data (the bin header included: the size
#: follows from dtype and shape), by (dtype, shape) of little-endian arrays: the same few shapes
#: go out at 1 kHz (bounded: clouds of every size are packed, not cached)
_ARRAY_HEADS: dict[tuple[np.dtype, tuple[int, ...]], bytes] = {}
_MAX_ARRAY_HEADS = 4096


def _array_head(a: np.ndarray) -> bytes:
    """The msgpack before a little-endian array's data (cached by dtype and shape)."""
    key = (a.dtype, a.shape)
    head = _ARRAY_HEADS.get(key)
    if head is None:
        head = b"".join((b"\x83", _ARRAY_KEYS[0], _packb(wire_dtype_name(a.dtype)),
                         _ARRAY_KEYS[2], _packb(list(a.shape)), _ARRAY_KEYS[4],
                         _bin_header(a.nbytes)))  # fmt: skip
        if len(_ARRAY_HEADS) < _MAX_ARRAY_HEADS:
            _ARRAY_HEADS[key] = head
    return head


def _pack_array(a: np.ndarray, out: list) -> None:
    head = _ARRAY_HEADS.get((a.dtype, a.shape))  # (a big-endian dtype is never a key)
    if head is None or not a.flags.c_contiguous:
        if a.dtype.byteorder == ">" or not a.flags.c_contiguous:
            wire = array_to_wire(a)
            a = np.frombuffer(wire["bytes"], _LITTLE[wire["dtype"]]).reshape(wire["shape"])
        head = _array_head(a)
    # a C-contiguous array is itself a bytes-like object to the final join: its data is
    # copied once, there, with no view or memoryview made per array
    out += (head, a)


#: the msgpack of each model's field names, in order (a model's fields never change)
_FIELD_KEYS: dict[type, list[tuple[str, bytes]]] = {}


def _field_keys(cls: type[BaseModel]) -> list[tuple[str, bytes]]:
    keys = _FIELD_KEYS.get(cls)
    if keys is None:
        keys = _FIELD_KEYS[cls] = [(k, _packb(k)) for k in cls.model_fields]
    return keys


_SCALARS = (int, float, str, bool, type(None))


def _pack(value: Any, out: list) -> None:
    """Append the msgpack encoding of ``value`` to ``out`` as chunks; array data is appended as
    a memoryview, so the final ``b"".join`` copies each array exactly once."""
    t = type(value)
    if t in _SCALARS:
        out.append(_packb(value))
    elif t is np.ndarray:
        _pack_array(value, out)
    elif isinstance(value, BaseModel):
        keys = _field_keys(t)
        out.append(_header(0x80, 16, 0xDE, 0xDF, len(keys)))
        for k, packed in keys:
            out.append(packed)
            _pack(getattr(value, k), out)
    elif isinstance(value, np.ndarray):
        _pack_array(value, out)
    elif isinstance(value, dict):
        out.append(_header(0x80, 16, 0xDE, 0xDF, len(value)))
        for k, v in value.items():
            out.append(_packb(k))
            _pack(v, out)
    elif isinstance(value, list | tuple):
        out.append(_header(0x90, 16, 0xDC, 0xDD, len(value)))
        for v in value:
            _pack(v, out)
    elif isinstance(value, np.generic):
        out.append(_packb(value.item()))
    else:
        out.append(_packb(value))


#: the envelope of each message class: map header, schema and version
_ENVELOPES: dict[type, bytes] = {}


def _envelope(cls: type[Message]) -> bytes:
    envelope = _ENVELOPES.get(cls)
    if envelope is None:
        if cls.SCHEMA not in REGISTRY:
            raise TypeError(f"{cls.__name__} is not a registered message")
        envelope = _ENVELOPES[cls] = b"".join((
            _header(0x80, 16, 0xDE, 0xDF, len(cls.model_fields) + 2),
            _packb("schema"), _packb(cls.SCHEMA), _packb("version"), _packb(cls.VERSION),
        ))  # fmt: skip
    return envelope


def encode(message: Message) -> bytes:
    """The msgpack bytes of ``message``, envelope included: exactly what ``msgpack.packb`` gives
    for the equivalent plain map, built with a single copy of each array."""
    cls = type(message)
    out: list = [_envelope(cls)]
    for k, packed in _field_keys(cls):
        out.append(packed)
        _pack(getattr(message, k), out)
    return b"".join(out)


#: each message class's field defaults (``_REQUIRED`` where a field has none, or a factory)
_DEFAULTS: dict[type, dict[str, Any]] = {}
_REQUIRED = object()


def encode_fields(cls: type[M], **values: Any) -> bytes:
    """``encode(cls.model_construct(**values))`` without building the model (a fifth of an IMU
    sample's cost at its producer): for the 1 kHz streams built from a service's own state.
    Nothing is validated here (every receiver validates what it decodes); a field left out
    takes its default, and a name that is not a field, or a required field left out, is a
    ``TypeError``."""
    defaults = _DEFAULTS.get(cls)
    if defaults is None:
        defaults = _DEFAULTS[cls] = {
            k: _REQUIRED if f.is_required() or f.default_factory is not None else f.default
            for k, f in cls.model_fields.items()
        }
    out: list = [_envelope(cls)]
    used = 0
    for k, packed in _field_keys(cls):
        if k in values:
            value = values[k]
            used += 1
        else:
            value = defaults[k]
            if value is _REQUIRED:
                raise TypeError(f"{cls.__name__}: field {k!r} is required (or has a factory)")
        out.append(packed)
        _pack(value, out)
    if used != len(values):
        unknown = sorted(set(values) - set(defaults))
        raise TypeError(f"{cls.__name__} has no field(s) {unknown}")
    return b"".join(out)


def peek(payload: bytes | bytearray | memoryview, *names: str, limit: int | None = 512) -> dict:
    """The top-level fields ``names`` of a message read from its first ``limit`` bytes (None:
    all of them), without decoding (or validating) the rest: other fields are skipped, not
    built. A 2 MB frame's seq and camera in microseconds. Fields beyond ``limit`` (or absent)
    are missing from the result."""
    unpacker = msgpack.Unpacker(raw=False, max_buffer_size=max(len(payload), 1))
    unpacker.feed(payload if limit is None else bytes(payload[:limit]))
    found: dict = {}
    try:
        for _ in range(unpacker.read_map_header()):
            key = unpacker.unpack()
            if key not in names:
                unpacker.skip()
                continue
            found[key] = unpacker.unpack()
            if len(found) == len(names):
                break
    except (msgpack.OutOfData, ValueError, msgpack.ExtraData, msgpack.UnpackException):
        pass
    return found


def _validation_text(schema: str, error: ValidationError) -> str:
    parts = []
    for e in error.errors(include_url=False)[:3]:
        loc = ".".join(str(p) for p in e["loc"]) or "(message)"
        parts.append(f"{loc}: {e['msg']}")
    more = error.error_count() - len(parts)
    return f"{schema}: " + "; ".join(parts) + (f" (+{more} more)" if more > 0 else "")


def decode(
    payload: bytes | bytearray | memoryview,
    expect: type[M] | tuple[type[Message], ...] | None = None,
) -> M:
    """Decode one message; with ``expect`` (a type or a tuple of types), refuse any other.

    Arrays in the result are read-only views of the payload's bytes.
    """
    try:
        data = msgpack.unpackb(payload, raw=False, use_list=True, strict_map_key=True)
    except Exception as e:
        raise CodecError("malformed", f"payload is not one msgpack object: {e}") from None
    if not isinstance(data, dict):
        raise CodecError("not_a_message", f"payload is a msgpack {type(data).__name__}, not a map")
    schema, version = data.pop("schema", None), data.pop("version", None)
    if not isinstance(schema, str) or not isinstance(version, int) or isinstance(version, bool):
        raise CodecError("not_a_message", "payload has no schema name and version")
    cls = REGISTRY.get(schema)
    if cls is None:
        raise CodecError("unknown_schema", f"unknown schema {schema!r}", schema)
    if version != cls.VERSION:
        raise CodecError(
            "wrong_version",
            f"{schema} version {version} is not the supported version {cls.VERSION}",
            schema,
        )
    if expect is not None and not issubclass(cls, expect):
        wanted = " or ".join(
            t.SCHEMA or t.__name__ for t in (expect if isinstance(expect, tuple) else (expect,))
        )
        raise CodecError("unexpected_schema", f"expected {wanted}, got {schema}", schema)
    try:
        return cls.model_validate(data, context=WIRE_CONTEXT)  # type: ignore[return-value]
    except ValidationError as e:
        raise CodecError("invalid", _validation_text(schema, e), schema) from None
    except Exception as e:  # a validator tripped on input it did not foresee
        raise CodecError("invalid", f"{schema}: {type(e).__name__}: {e}", schema) from None
