"""numpy arrays inside pydantic models, and their wire form.

On the wire an array is the msgpack map
``{"dtype": "float32", "shape": [480, 640], "bytes": <bin>}`` holding C-order, little-endian
bytes. Decoding builds the array with ``np.frombuffer`` on the received bytes, so a decoded array
is a read-only view and costs no copy.

A field declares its array with ``Annotated[np.ndarray, Array("float32", ("h", "w"))]``. A shape
entry is an int (that exact size), ``None`` (any size) or a name: arrays (and ``Dim``-tagged lists)
of one model that use the same name must agree on that size, which the model checks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import GetCoreSchemaHandler, GetJsonSchemaHandler, ValidationInfo
from pydantic_core import PydanticCustomError, core_schema

#: dtypes allowed on the wire, by their canonical name (always little-endian).
WIRE_DTYPES: frozenset[str] = frozenset(
    {"bool", "uint8", "uint16", "uint32", "int8", "int16", "int32", "int64", "float32", "float64"}
)

WIRE_KEYS = frozenset({"dtype", "shape", "bytes"})
_LITTLE = {name: np.dtype(name).newbyteorder("<") for name in WIRE_DTYPES}

#: context flag the codec passes to ``model_validate``: arrays must then be in wire form.
WIRE_CONTEXT = {"wire": True}

ShapeEntry = int | str | None


def wire_dtype_name(dtype: np.dtype) -> str:
    """The wire name of a (little-endian or native) dtype: ``dtype.name``, looked up instead of
    computed (numpy builds the name in Python on every access)."""
    name = _NAMES.get(dtype)
    if name is None:
        name = _NAMES[dtype] = dtype.name
    return name


_NAMES: dict[np.dtype, str] = {dt: name for name, dt in _LITTLE.items()}


def array_to_wire(a: np.ndarray) -> dict[str, Any]:
    """The wire map of an array; the bytes are a view of ``a`` when it is already contiguous."""
    if a.dtype.byteorder == ">":
        a = a.astype(a.dtype.newbyteorder("<"))
    a = np.ascontiguousarray(a)
    raw = memoryview(a.reshape(-1).view(np.uint8))
    return {"dtype": wire_dtype_name(a.dtype), "shape": list(a.shape), "bytes": raw}


def array_from_wire(value: Any) -> np.ndarray:
    """Build a read-only array over the wire map's bytes; raises ``ValueError`` on any mismatch."""
    # the common case first, checked field by field without a generator (1 kHz messages carry
    # 3-vectors): a one-dimensional array of a wire dtype whose bytes have its size exactly
    if type(value) is dict and len(value) == 3:
        dtype, shape, data = value.get("dtype"), value.get("shape"), value.get("bytes")
        dt = _LITTLE.get(dtype) if type(dtype) is str else None
        if (
            dt is not None
            and type(shape) is list
            and len(shape) == 1
            and type(shape[0]) is int
            and shape[0] >= 0
            and type(data) is bytes
            and len(data) == shape[0] * dt.itemsize
        ):
            return np.frombuffer(data, dtype=dt)
    if not isinstance(value, dict) or value.keys() != WIRE_KEYS:
        raise ValueError("expected an array map with exactly the keys dtype, shape, bytes")
    dtype, shape, data = value["dtype"], value["shape"], value["bytes"]
    dt = _LITTLE.get(dtype) if isinstance(dtype, str) else None
    if dt is None:
        raise ValueError(f"unsupported array dtype {dtype!r}")
    if not isinstance(shape, list | tuple) or not all(
        type(s) is int and s >= 0
        for s in shape  # (not bool: type, not isinstance)
    ):
        raise ValueError(f"array shape must be a list of non-negative ints, got {shape!r}")
    if not isinstance(data, bytes | bytearray | memoryview):
        raise ValueError("array bytes must be a msgpack bin")
    expected = math.prod(shape) * dt.itemsize
    if len(data) != expected:
        raise ValueError(
            f"array bytes ({len(data)}) do not match shape {list(shape)} of {dtype} "
            f"({expected} bytes): truncated or padded"
        )
    return np.frombuffer(data, dtype=dt).reshape(shape)


@dataclass(frozen=True)
class Array:
    """Pydantic annotation for an ``np.ndarray`` field of a given dtype and shape."""

    dtype: str
    shape: tuple[ShapeEntry, ...] | None = None
    max_rows: int | None = None
    description: str = ""

    def __post_init__(self) -> None:
        if self.dtype not in WIRE_DTYPES:
            raise ValueError(f"Array dtype {self.dtype!r} is not a wire dtype")

    def named_dims(self) -> dict[int, str]:
        """Axis index → dimension name, for the shape entries that are names."""
        return {i: s for i, s in enumerate(self.shape or ()) if isinstance(s, str)}

    def shape_text(self) -> str:
        if self.shape is None:
            return "any shape"
        return "[" + ", ".join("*" if s is None else str(s) for s in self.shape) + "]"

    def _check(self, a: np.ndarray) -> np.ndarray:
        if a.dtype != _LITTLE[self.dtype] and a.dtype.name != self.dtype:  # (fast path first)
            raise PydanticCustomError(
                "array_dtype",
                "expected {want} array, got {got}",
                {"want": self.dtype, "got": a.dtype.name},
            )
        if self.shape is not None:
            if a.ndim != len(self.shape):
                raise PydanticCustomError(
                    "array_shape",
                    "expected shape {want}, got {got}",
                    {"want": self.shape_text(), "got": list(a.shape)},
                )
            for want, got in zip(self.shape, a.shape, strict=True):
                if isinstance(want, int) and want != got:
                    raise PydanticCustomError(
                        "array_shape",
                        "expected shape {want}, got {got}",
                        {"want": self.shape_text(), "got": list(a.shape)},
                    )
        if self.max_rows is not None and a.ndim > 0 and a.shape[0] > self.max_rows:
            raise PydanticCustomError(
                "array_rows",
                "at most {n} rows allowed, got {got}",
                {"n": self.max_rows, "got": a.shape[0]},
            )
        return a

    def validate(self, value: Any, info: ValidationInfo) -> np.ndarray:
        wire = bool(info.context and info.context.get("wire"))
        if isinstance(value, np.ndarray) and not wire:
            if value.dtype != _LITTLE[self.dtype] and np.can_cast(
                value.dtype, self.dtype, "same_kind"
            ):
                value = value.astype(self.dtype)
            return self._check(value)
        if isinstance(value, dict):
            try:
                return self._check(array_from_wire(value))
            except ValueError as e:
                raise PydanticCustomError("array_wire", "{reason}", {"reason": str(e)}) from None
        if wire:
            raise PydanticCustomError(
                "array_type",
                "expected an array map {{dtype, shape, bytes}}, got {got}",
                {"got": type(value).__name__},
            )
        if isinstance(value, Sequence) and not isinstance(value, str | bytes):
            return self._check(np.asarray(value, dtype=self.dtype))
        raise PydanticCustomError(
            "array_type", "expected an ndarray, got {got}", {"got": type(value).__name__}
        )

    def __get_pydantic_core_schema__(self, source: Any, handler: GetCoreSchemaHandler):
        return core_schema.with_info_plain_validator_function(self.validate)

    def __get_pydantic_json_schema__(self, schema: Any, handler: GetJsonSchemaHandler) -> dict:
        shape_schema: dict[str, Any] = {"type": "array", "items": {"type": "integer", "minimum": 0}}
        if self.shape is not None:
            shape_schema["minItems"] = shape_schema["maxItems"] = len(self.shape)
            shape_schema["prefixItems"] = [
                {"const": s} if isinstance(s, int) else {"type": "integer", "minimum": 0}
                for s in self.shape
            ]
        text = f"{self.dtype} array, shape {self.shape_text()}"
        if self.max_rows is not None:
            text += f", at most {self.max_rows} rows"
        if self.description:
            text = f"{self.description} — {text}"
        return {
            "type": "object",
            "description": text + ". C-order little-endian bytes.",
            "properties": {
                "dtype": {"const": self.dtype},
                "shape": shape_schema,
                "bytes": {"type": "string", "contentMediaType": "application/octet-stream"},
            },
            "required": ["dtype", "shape", "bytes"],
            "additionalProperties": False,
        }


@dataclass(frozen=True)
class Dim:
    """Tags a list field with a dimension name shared with arrays of the same model."""

    name: str
