"""Hypothesis strategies for every model of ``schemas``, derived from the field annotations.

Arrays get their declared dtype and shape (named dimensions agree within a model), poses are
random rigid transforms, quaternions and directions unit length; scalar constraints (ge, gt,
le, lt, min_length) are honoured. Cross-field rules that annotations cannot express are patched
by the ``FIXUPS`` of the few models that have them.
"""

from __future__ import annotations

import math
import types
import typing
from collections.abc import Callable
from typing import Any

import annotated_types as at
import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from pydantic import BaseModel

from schemas import (
    ArmCommand,
    ExploreControl,
    PlanRequest,
    RgbdFrame,
    SceneGraph,
    SimControl,
)
from schemas.arrays import Array, Dim
from schemas.base import field_metadata
from schemas.occupancy import BoxQuery
from schemas.types import Finite, Rigid, UnitQuaternion, UnitVector

MAX_DIM = 5


def _unit(draw, n: int) -> np.ndarray:
    v = np.array(draw(st.lists(st.floats(-1, 1), min_size=n, max_size=n)), dtype=np.float64)
    norm = np.linalg.norm(v)
    if norm < 1e-3:
        v = np.zeros(n)
        v[0] = 1.0
        return v
    return v / norm


def _rigid(draw) -> np.ndarray:
    w, x, y, z = _unit(draw, 4)
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = draw(st.lists(st.floats(-100, 100), min_size=3, max_size=3))
    return T


def _array(draw, spec: Array, markers: list[Any], dims: dict[str, int]) -> np.ndarray:
    shape = []
    for i, s in enumerate(spec.shape or (None,)):
        if isinstance(s, int):
            shape.append(s)
        elif isinstance(s, str):
            shape.append(dims.setdefault(s, draw(st.integers(1, MAX_DIM))))
        else:
            hi = MAX_DIM if i > 0 or spec.max_rows is None else min(MAX_DIM, spec.max_rows)
            shape.append(draw(st.integers(0, hi)))
    if any(isinstance(m, Rigid) for m in markers):
        stack = [_rigid(draw) for _ in range(int(np.prod(shape[:-2], dtype=int)))]
        return np.array(stack, dtype=np.float64).reshape(shape)
    if any(isinstance(m, UnitQuaternion | UnitVector) for m in markers):
        return _unit(draw, shape[-1])
    dtype = np.dtype(spec.dtype)
    finite = any(isinstance(m, Finite) for m in markers)
    elements = None
    if dtype.kind == "f":
        elements = st.floats(
            width=dtype.itemsize * 8, allow_nan=not finite, allow_infinity=not finite
        )
    return draw(hnp.arrays(dtype, tuple(shape), elements=elements))


def _bounds(metadata: list[Any]) -> dict[str, Any]:
    b: dict[str, Any] = {}
    for m in metadata:
        if isinstance(m, at.Ge):
            b["min_value"] = m.ge
        elif isinstance(m, at.Gt):
            b["min_value"], b["exclude_min"] = m.gt, True
        elif isinstance(m, at.Le):
            b["max_value"] = m.le
        elif isinstance(m, at.Lt):
            b["max_value"], b["exclude_max"] = m.lt, True
        elif isinstance(m, at.MinLen):
            b["min_size"] = m.min_length
    return b


def draw_value(draw, annotation: Any, metadata: list[Any], dims: dict[str, int]) -> Any:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        inner, *extra = typing.get_args(annotation)
        return draw_value(draw, inner, metadata + list(extra), dims)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(options) < len(typing.get_args(annotation)) and draw(st.booleans()):
            return None
        choice = draw(st.sampled_from(options))
        return draw_value(draw, choice, metadata, dims)
    spec = next((m for m in metadata if isinstance(m, Array)), None)
    if spec is not None:
        return _array(draw, spec, metadata, dims)
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return draw(model_strategy(annotation))
    if origin is typing.Literal:
        return draw(st.sampled_from(typing.get_args(annotation)))
    bounds = _bounds(metadata)
    if annotation is bool:
        return draw(st.booleans())
    if annotation is int:
        lo = math.ceil(bounds.get("min_value", -(2**53)))
        if bounds.get("exclude_min"):
            lo += 1
        hi = int(bounds.get("max_value", 2**53))
        return draw(st.integers(lo, hi))
    if annotation is float:
        kwargs = {k: v for k, v in bounds.items() if k != "min_size"}
        kwargs.setdefault("min_value", -1e9)
        kwargs.setdefault("max_value", 1e9)
        return draw(st.floats(allow_nan=False, allow_infinity=False, **kwargs))
    if annotation is str:
        return draw(st.text(min_size=bounds.get("min_size", 0), max_size=12))
    if origin is list:
        (item,) = typing.get_args(annotation)
        dim = next((m for m in metadata if isinstance(m, Dim)), None)
        if dim is not None:
            n = dims.setdefault(dim.name, draw(st.integers(1, MAX_DIM)))
            return [draw_value(draw, item, [], dims) for _ in range(n)]
        return [draw_value(draw, item, [], {}) for _ in range(draw(st.integers(0, 3)))]
    if origin is tuple:
        return tuple(draw_value(draw, a, [], dims) for a in typing.get_args(annotation))
    if origin is dict:
        key_t, value_t = typing.get_args(annotation)
        n = draw(st.integers(0, 3))
        return {
            draw_value(draw, key_t, [], {}): draw_value(draw, value_t, [], {}) for _ in range(n)
        }
    raise TypeError(f"no strategy for {annotation!r}")


# -- cross-field rules ---------------------------------------------------------------------------


def _fix_rgbd(draw, values: dict, dims: dict) -> None:
    if values.get("rgb") is None and values.get("depth") is None:
        values["depth"] = _array(draw, Array("float32", ("h", "w")), [], dims)
    if values.get("joint_positions") is not None:  # a name per position
        n = len(values["joint_positions"])
        values["joint_names"] = [draw(st.text(min_size=1, max_size=8)) for _ in range(n)]
    else:
        values["joint_names"] = []
    h, w = dims["h"], dims["w"]
    values["intrinsics"] = values["intrinsics"].model_copy(update={"width": w, "height": h})


def _fix_scene_graph(draw, values: dict, dims: dict) -> None:
    prims = [p.model_copy(update={"id": i}) for i, p in enumerate(values.get("primitives", []))]
    values["primitives"] = prims
    ids = st.integers(0, len(prims) - 1) if prims else None

    def relink(items: list, fields: tuple[str, ...]) -> list:
        if ids is None:
            return []
        return [i.model_copy(update={f: draw(ids) for f in fields}) for i in items]

    values["spatial_edges"] = relink(values.get("spatial_edges", []), ("a", "b"))
    values["support_edges"] = relink(values.get("support_edges", []), ("supporter", "supported"))
    values["affordances"] = relink(values.get("affordances", []), ("primitive_id",))
    for key in ("unstable_ids", "unresolved_ids"):
        values[key] = [draw(ids) for _ in values.get(key, [])] if ids is not None else []
    values["root_id"] = draw(ids) if ids is not None and values.get("root_id") is not None else None


def _fix_box(draw, values: dict, dims: dict) -> None:
    lo, hi = values["box_min"], values["box_max"]
    values["box_min"], values["box_max"] = np.minimum(lo, hi), np.maximum(lo, hi)


def _fix_roi(draw, values: dict, dims: dict) -> None:
    """An roi comes whole (both corners or neither), its min below its max."""
    lo, hi = values.get("roi_min"), values.get("roi_max")
    if lo is None or hi is None:
        values.pop("roi_min", None)
        values.pop("roi_max", None)
        return
    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
    same = lo >= hi
    values["roi_min"], values["roi_max"] = np.where(same, 0.0, lo), np.where(same, 1.0, hi)


def _fix_sim_control(draw, values: dict, dims: dict) -> None:
    if values.get("op") == "set_disturbance" and not values.get("joint"):
        values["joint"] = "hip_yaw"


def _fix_arm(draw, values: dict, dims: dict) -> None:
    n = dims.setdefault("n", draw(st.integers(1, MAX_DIM)))
    values["names"] = [draw(st.text(min_size=1, max_size=8)) for _ in range(n)]
    values["values"] = _array(draw, Array("float64", ("n",)), [Finite()], dims)
    values["goal"] = _rigid(draw)
    if values.get("gripper") is None:
        values["gripper"] = draw(st.floats(0.0, 1.0))


FIXUPS: dict[type, Callable[[Any, dict, dict], None]] = {
    ArmCommand: _fix_arm,
    RgbdFrame: _fix_rgbd,
    SceneGraph: _fix_scene_graph,
    BoxQuery: _fix_box,
    SimControl: _fix_sim_control,
    ExploreControl: _fix_roi,
    PlanRequest: _fix_roi,
}

_cache: dict[type, st.SearchStrategy] = {}


def model_strategy(cls: type[BaseModel]) -> st.SearchStrategy:
    """Valid instances of ``cls`` with optional fields sometimes left at their defaults."""
    if cls in _cache:
        return _cache[cls]

    @st.composite
    def build(draw):
        dims: dict[str, int] = {}
        values: dict[str, Any] = {}
        for name, info in cls.model_fields.items():
            if not info.is_required() and draw(st.booleans()):
                continue
            values[name] = draw_value(draw, info.annotation, field_metadata(info), dims)
        for base, fix in FIXUPS.items():
            if issubclass(cls, base):
                fix(draw, values, dims)
        return cls(**values)

    _cache[cls] = build()
    return _cache[cls]
