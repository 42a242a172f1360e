"""The scene memory's state as data, not code: a snapshot file a data volume hands back can
describe a state but never run anything (pickle would run whatever it holds).

``dump(state)`` walks the state: numpy arrays go into one ``.npz`` (loaded with
``allow_pickle=False``), everything else into a msgpack tree in which an object is
``{"__object__": name, "state": ...}`` for a class of ``ALLOWED`` only (its ``__getstate__``
honoured: the occupancy map keeps its known voxels only), a pydantic model
``{"__model__": name, "fields": ...}``, tuples and non-string-keyed dicts tagged likewise.
``load`` rebuilds that and refuses any other class name with ``StateError``.

File: ``MAGIC`` + sha-256 of the body + body (msgpack ``{"version", "n", "tree", "arrays"}``);
a truncated or altered file fails its checksum and is refused.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
from typing import Any

import msgpack
import numpy as np
from pydantic import BaseModel

from schemas import scene as scene_schemas
from services.scene_memory import (
    correction_filter,
    fusion,
    hypotheses,
    memory,
    occupancy,
    outline,
    registration,
    voxel_map,
)

MAGIC = b"AVS-SCENE-MEMORY\x00"
VERSION = 1

#: the classes a snapshot may name, and nothing else
ALLOWED: dict[str, type] = {
    cls.__qualname__: cls
    for cls in (
        memory.SceneMemory,
        memory.MemoryConfig,
        fusion.Fusion,
        fusion.FusionConfig,
        fusion.MemoryPrimitive,
        fusion.Update,
        occupancy.OccupancyMap,
        occupancy.OccupancyConfig,
        registration.RegistrationConfig,
        registration.Pass,
        registration.RegistrationMap,
        hypotheses.SearchConfig,
        outline.OutlineConfig,
        correction_filter.CorrectionFilter,
        correction_filter.OdometryNoise,
        correction_filter.RegistrationNoise,
        voxel_map.VoxelMap,
    )
}
MODELS: dict[str, type[BaseModel]] = {
    name: cls
    for name, cls in vars(scene_schemas).items()
    if isinstance(cls, type) and issubclass(cls, BaseModel) and cls.__module__ == "schemas.scene"
}


class StateError(ValueError):
    """A snapshot that cannot be trusted: wrong magic, checksum, version or content."""


class _Arrays(list):
    """The arrays a tree refers to, and which of them ``capture`` may keep without a copy."""

    def __init__(self) -> None:
        super().__init__()
        self.as_is: set[int] = set()


def _to_tree(value: Any, arrays: _Arrays, copy: bool = True) -> Any:
    if isinstance(value, np.ndarray):
        arrays.append(value)
        if not copy:
            arrays.as_is.add(len(arrays) - 1)
        return {"__array__": len(arrays) - 1}
    if isinstance(value, np.generic):
        return value.item()
    if value is None or isinstance(value, (bool, int, float, str, bytes)):
        return value
    if isinstance(value, tuple):
        return {"__tuple__": [_to_tree(v, arrays) for v in value]}
    if isinstance(value, list):
        return [_to_tree(v, arrays) for v in value]
    if isinstance(value, dict):
        if all(isinstance(k, str) and not k.startswith("__") for k in value):
            return {k: _to_tree(v, arrays) for k, v in value.items()}
        return {"__items__": [[_to_tree(k, arrays), _to_tree(v, arrays)] for k, v in value.items()]}
    if isinstance(value, BaseModel):
        name = type(value).__name__
        if MODELS.get(name) is not type(value):
            raise TypeError(f"{name} is not a scene schema a snapshot may hold")
        fields = {k: getattr(value, k) for k in type(value).model_fields}
        return {"__model__": name, "fields": _to_tree(fields, arrays)}
    name = type(value).__qualname__
    if ALLOWED.get(name) is not type(value):
        raise TypeError(f"{name} is not a class a snapshot may hold")
    if hasattr(value, "__getstate__") and type(value).__getstate__ is not object.__getstate__:
        state = value.__getstate__()
    elif dataclasses.is_dataclass(value):
        state = {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    else:
        state = dict(vars(value))
    as_is = getattr(type(value), "SNAPSHOT_AS_IS", frozenset())
    if as_is and isinstance(state, dict):
        tree = {k: _to_tree(v, arrays, k not in as_is) for k, v in state.items()}
        return {"__object__": name, "state": tree}
    return {"__object__": name, "state": _to_tree(state, arrays)}


def _from_tree(tree: Any, arrays: dict[str, np.ndarray]) -> Any:
    if isinstance(tree, list):
        return [_from_tree(v, arrays) for v in tree]
    if not isinstance(tree, dict):
        return tree
    if "__array__" in tree:
        return arrays[f"a{tree['__array__']}"]
    if "__tuple__" in tree:
        return tuple(_from_tree(v, arrays) for v in tree["__tuple__"])
    if "__items__" in tree:
        return {_key(_from_tree(k, arrays)): _from_tree(v, arrays) for k, v in tree["__items__"]}
    if "__model__" in tree:
        cls = MODELS.get(tree["__model__"])
        if cls is None:
            raise StateError(f"a snapshot names {tree['__model__']!r}, not a scene schema")
        return cls.model_validate(_from_tree(tree["fields"], arrays))
    if "__object__" in tree:
        cls = ALLOWED.get(tree["__object__"])
        if cls is None:
            raise StateError(f"a snapshot names class {tree['__object__']!r}: not allowed")
        state = _from_tree(tree["state"], arrays)
        if dataclasses.is_dataclass(cls) and not hasattr(cls, "__setstate__"):
            return cls(**state)
        obj = cls.__new__(cls)
        if hasattr(obj, "__setstate__"):
            obj.__setstate__(state)
        else:
            obj.__dict__.update(state)
        return obj
    return {k: _from_tree(v, arrays) for k, v in tree.items()}


def _key(k: Any) -> Any:
    return tuple(k) if isinstance(k, list) else k


def dump(state: Any, n: int) -> bytes:
    """The file's bytes for ``state`` as of update ``n``."""
    return serialise(*capture(state), n)


def capture(state: Any) -> tuple[Any, list[np.ndarray]]:
    """``state`` as a tree and its arrays: what the file will hold, taken while the state
    stands still; ``serialise`` makes the bytes of it later, while the state changes. Arrays
    are copied, except those a class names in ``SNAPSHOT_AS_IS`` (keys of its state): made
    fresh by its ``__getstate__``, or only ever replaced, never written in place. Fresh pages
    are what a copy costs most: in the live stack a kitchen capture took 0.4-1 s under the
    scene memory's locks, most of it page faults."""
    arrays = _Arrays()
    tree = _to_tree(state, arrays)
    return tree, [a if i in arrays.as_is else np.array(a, copy=True) for i, a in enumerate(arrays)]


def serialise(tree: Any, arrays: list[np.ndarray], n: int) -> bytes:
    """The file's bytes of a ``capture`` as of update ``n``."""
    buffer = io.BytesIO()
    np.savez(buffer, **{f"a{i}": a for i, a in enumerate(arrays)})
    body = msgpack.packb(
        {"version": VERSION, "n": n, "tree": tree, "arrays": buffer.getvalue()},
        use_bin_type=True,
    )
    return MAGIC + hashlib.sha256(body).digest() + body


def load(data: bytes) -> tuple[Any, int]:
    """(state, update number) from a file's bytes; ``StateError`` for anything untrustworthy."""
    if not data.startswith(MAGIC):
        raise StateError("not a scene memory snapshot (wrong magic)")
    digest, body = data[len(MAGIC) : len(MAGIC) + 32], data[len(MAGIC) + 32 :]
    if hashlib.sha256(body).digest() != digest:
        raise StateError("checksum mismatch: the snapshot is truncated or altered")
    try:
        content = msgpack.unpackb(body, raw=False, strict_map_key=False)
        if content.get("version") != VERSION:
            raise StateError(f"snapshot version {content.get('version')}, expected {VERSION}")
        with np.load(io.BytesIO(content["arrays"]), allow_pickle=False) as npz:
            arrays = {k: npz[k] for k in npz.files}
        return _from_tree(content["tree"], arrays), int(content["n"])
    except StateError:
        raise
    except Exception as e:  # a checksum-valid file written by something else
        raise StateError(f"unreadable snapshot: {type(e).__name__}: {e}") from None
