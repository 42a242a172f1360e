"""Base classes of the wire contract: ``Model`` (any part of a message) and ``Message``.

Every ``Message`` subclass names itself with ``SCHEMA`` and ``VERSION``; both travel in the
envelope of each encoded message and are checked on decode. Subclasses register themselves, so
``REGISTRY`` always lists every message the system speaks.
"""

from __future__ import annotations

import math
from types import UnionType
from typing import Annotated, Any, ClassVar, Union, get_args, get_origin

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic.fields import FieldInfo

from schemas.arrays import Array, Dim

#: schema name → message class, filled by ``Message.__init_subclass__``.
REGISTRY: dict[str, type[Message]] = {}


def field_metadata(info: FieldInfo) -> list[Any]:
    """A field's annotation metadata, including that of ``Annotated[...] | None`` members."""
    found = list(info.metadata)
    stack = [info.annotation]
    while stack:
        t = stack.pop()
        if get_origin(t) is Annotated:
            found.extend(t.__metadata__)
            stack.append(get_args(t)[0])
        elif get_origin(t) in (Union, UnionType):
            stack.extend(get_args(t))
    return found


def _field_dims(cls: type[BaseModel]) -> list[tuple[str, Array | Dim]]:
    out = []
    for name, info in cls.model_fields.items():
        for meta in field_metadata(info):
            if (isinstance(meta, Array) and meta.named_dims()) or isinstance(meta, Dim):
                out.append((name, meta))
    return out


def _values_equal(a: Any, b: Any) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if not (isinstance(a, np.ndarray) and isinstance(b, np.ndarray)):
            return False
        if a.dtype != b.dtype or a.shape != b.shape:
            return False
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind == "f"))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(_values_equal(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_values_equal(a[k], b[k]) for k in a)
    return bool(a == b)


class Model(BaseModel):
    """Any structure on the wire: strict about unknown fields, finite scalars, arrays by value."""

    model_config = ConfigDict(
        extra="forbid",
        arbitrary_types_allowed=True,
        allow_inf_nan=False,
        validate_default=False,
    )

    _dims: ClassVar[list[tuple[str, Array | Dim]]] = []

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        cls._dims = _field_dims(cls)

    @model_validator(mode="after")
    def _check_named_dims(self) -> Model:
        """Arrays and Dim-tagged lists that share a dimension name must agree on its size."""
        if not self._dims:
            return self
        seen: dict[str, tuple[int, str]] = {}
        for field, meta in self._dims:
            value = getattr(self, field)
            if value is None:
                continue
            sizes = (
                [(meta.name, len(value))]
                if isinstance(meta, Dim)
                else [(name, value.shape[axis]) for axis, name in meta.named_dims().items()]
            )
            for name, size in sizes:
                if name in seen and seen[name][0] != size:
                    other_size, other_field = seen[name]
                    raise ValueError(
                        f"dimension {name!r} is {other_size} in {other_field} but {size} in {field}"
                    )
                seen.setdefault(name, (size, field))
        return self

    def __eq__(self, other: object) -> bool:
        if type(self) is not type(other):
            return NotImplemented
        return all(
            _values_equal(getattr(self, k), getattr(other, k)) for k in type(self).model_fields
        )

    __hash__ = None  # type: ignore[assignment]


def _envelope_json_schema(schema: dict[str, Any], cls: type[Message]) -> None:
    props = schema.setdefault("properties", {})
    schema["properties"] = {
        "schema": {"const": cls.SCHEMA, "description": "message name"},
        "version": {"const": cls.VERSION, "description": "schema version"},
        **props,
    }
    schema["required"] = ["schema", "version", *schema.get("required", [])]
    schema["$id"] = f"avs/{cls.SCHEMA}/v{cls.VERSION}"


class Message(Model):
    """A top-level message; subclasses may set ``SCHEMA`` (default: the class name) and
    ``VERSION``."""

    SCHEMA: ClassVar[str] = ""
    VERSION: ClassVar[int] = 1
    #: set in a class's own body to keep it out of the registry (a base of other messages).
    ABSTRACT: ClassVar[bool] = True

    model_config = ConfigDict(json_schema_extra=_envelope_json_schema)

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("ABSTRACT", False):
            return
        if "SCHEMA" not in cls.__dict__:
            cls.SCHEMA = cls.__name__
        if cls.SCHEMA in REGISTRY and REGISTRY[cls.SCHEMA] is not cls:
            raise TypeError(f"schema name {cls.SCHEMA!r} is registered twice")
        REGISTRY[cls.SCHEMA] = cls

    @classmethod
    def __pydantic_init_subclass__(cls, **kwargs: Any) -> None:
        super().__pydantic_init_subclass__(**kwargs)
        clash = {"schema", "version"} & set(cls.model_fields)
        if clash:
            raise TypeError(f"{cls.__name__}: field names {sorted(clash)} are the envelope's")


class Stamped(Message):
    """A message of a stream: a monotonic sequence number and a time stamp."""

    ABSTRACT: ClassVar[bool] = True

    seq: int = Field(0, ge=0, description="monotonic sequence number of this stream")
    stamp: float = Field(0.0, description="time of the data in seconds (sim time or wall time)")
