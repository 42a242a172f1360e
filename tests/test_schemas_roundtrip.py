"""Every message survives encode → decode unchanged, whatever its contents."""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import REGISTRY, Message, decode, encode, encode_fields
from schemas.arrays import WIRE_DTYPES, Array
from schemas.base import Model, field_metadata
from tests.strategies import model_strategy

MESSAGES = sorted(REGISTRY.items())


@pytest.mark.parametrize(("name", "cls"), MESSAGES, ids=[n for n, _ in MESSAGES])
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_round_trip(name, cls, data):
    message = data.draw(model_strategy(cls))
    payload = encode(message)
    back = decode(payload)
    assert type(back) is cls
    assert back == message
    assert encode(back) == payload  # the wire form is canonical
    assert payload == msgpack.packb(_plain(message), use_bin_type=True)


def _plain(value):
    """A message as the plain map any msgpack library would build (arrays as dtype/shape/bytes)."""
    if isinstance(value, Message):
        return {"schema": value.SCHEMA, "version": value.VERSION, **_plain_fields(value)}
    if isinstance(value, Model):
        return _plain_fields(value)
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        return {"dtype": a.dtype.name, "shape": list(a.shape), "bytes": a.tobytes()}
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def _plain_fields(model):
    return {k: _plain(getattr(model, k)) for k in type(model).model_fields}


def _dtypes_in(cls: type[Model], seen: set[type]) -> set[str]:
    found = set()
    for info in cls.model_fields.values():
        for meta in field_metadata(info):
            if isinstance(meta, Array):
                found.add(meta.dtype)
        stack = [info.annotation]
        while stack:
            t = stack.pop()
            if isinstance(t, type) and issubclass(t, Model) and t not in seen:
                seen.add(t)
                found |= _dtypes_in(t, seen)
            stack.extend(getattr(t, "__args__", ()))
    return found


def test_every_array_dtype_in_use_is_a_wire_dtype_and_round_trips():
    used = set().union(*(_dtypes_in(cls, set()) for cls in REGISTRY.values()))
    assert used <= WIRE_DTYPES
    # the dtypes the contract uses today; a new one must be added here on purpose
    assert used == {"uint8", "float32", "float64", "int32", "bool"}


def test_decoded_arrays_are_views_of_the_payload():
    from schemas import CameraIntrinsics, RgbdFrame

    frame = RgbdFrame(
        camera="head_rgbd",
        intrinsics=CameraIntrinsics.from_fov(640, 480, 45.0),
        depth=np.ones((480, 640), np.float32),
        T_world_camera=np.eye(4),
    )
    back = decode(encode(frame))
    assert not back.depth.flags.writeable  # np.frombuffer over the received bytes
    assert back.depth.base is not None


@pytest.mark.parametrize(
    "make",
    [
        lambda: np.arange(12.0).reshape(3, 4)[:, ::2],  # strided
        lambda: np.asfortranarray(np.arange(12.0).reshape(3, 4)),
        lambda: np.arange(6.0).astype(">f8"),  # big-endian
        lambda: np.zeros((0, 3)),
        lambda: np.array([True, False, True]),
    ],
    ids=["strided", "fortran", "big_endian", "empty", "bool"],
)
def test_arrays_of_any_layout_go_out_as_their_little_endian_c_order_bytes(make):
    from schemas import codec

    a = make()
    raw = np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")))
    expected = {"dtype": raw.dtype.name, "shape": list(a.shape), "bytes": raw.tobytes()}
    for _ in range(2):  # the second time with the array's head cached
        out: list = []
        codec._pack_array(a, out)
        assert b"".join(out) == msgpack.packb(expected, use_bin_type=True)


@pytest.mark.parametrize(("name", "cls"), MESSAGES, ids=[n for n, _ in MESSAGES])
@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_encode_fields_is_encode_of_the_model(name, cls, data):
    message = data.draw(model_strategy(cls))
    fields = {k: getattr(message, k) for k in cls.model_fields}
    assert encode_fields(cls, **fields) == encode(message)


def test_encode_fields_takes_defaults_and_refuses_what_is_no_field():
    from schemas import ImuSample

    v = {"seq": 3, "stamp": 0.5, "angular_velocity": np.zeros(3),
         "linear_acceleration": np.zeros(3), "orientation": np.array([1.0, 0, 0, 0])}  # fmt: skip
    assert encode_fields(ImuSample, **v) == encode(ImuSample(**v))  # frame: its default
    with pytest.raises(TypeError, match="no field"):
        encode_fields(ImuSample, **v, frames="x")
    with pytest.raises(TypeError, match="orientation"):
        encode_fields(ImuSample, **{k: x for k, x in v.items() if k != "orientation"})
