"""msgpack codec of every AVS message.

A message on the wire is one msgpack map: ``{"schema": name, "version": n, <fields>}``. Nested
models are maps, numpy arrays are ``{"dtype", "shape", "bytes"}`` maps (see ``schemas.arrays``).
``decode`` refuses anything else with a ``CodecError`` — never another exception — whose
``kind`` says why (for drop counters) and whose text says where.
"""

from __future__ import annotations

from typing import Any, TypeVar

import msgpack
import numpy as np
from pydantic import BaseModel, ValidationError

from schemas.arrays import WIRE_CONTEXT, array_to_wire
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


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return array_to_wire(obj)
    if isinstance(obj, BaseModel):
        return {k: getattr(obj, k) for k in type(obj).model_fields}
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def encode(message: Message) -> bytes:
    """The msgpack bytes of ``message``, envelope included."""
    cls = type(message)
    if cls.SCHEMA not in REGISTRY:
        raise TypeError(f"{cls.__name__} is not a registered message")
    body = {"schema": cls.SCHEMA, "version": cls.VERSION}
    body.update((k, getattr(message, k)) for k in cls.model_fields)
    return msgpack.packb(body, default=_default, use_bin_type=True)


def _validation_text(schema: str, error: ValidationError) -> str:
    parts = []
    for e in error.errors(include_url=False)[:3]:
        loc = ".".join(str(p) for p in e["loc"]) or "(message)"
        parts.append(f"{loc}: {e['msg']}")
    more = error.error_count() - len(parts)
    return f"{schema}: " + "; ".join(parts) + (f" (+{more} more)" if more > 0 else "")


def decode(payload: bytes | bytearray | memoryview, expect: type[M] | None = None) -> M:
    """Decode one message; with ``expect``, refuse any other message type.

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
        raise CodecError("unexpected_schema", f"expected {expect.SCHEMA}, got {schema}", schema)
    try:
        return cls.model_validate(data, context=WIRE_CONTEXT)  # type: ignore[return-value]
    except ValidationError as e:
        raise CodecError("invalid", _validation_text(schema, e), schema) from None
    except Exception as e:  # a validator tripped on input it did not foresee
        raise CodecError("invalid", f"{schema}: {type(e).__name__}: {e}", schema) from None
