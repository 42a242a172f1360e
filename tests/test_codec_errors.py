"""Malformed payloads raise the codec's own error, with a reason, and never anything else."""

from __future__ import annotations

import contextlib

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from schemas import (
    CameraIntrinsics,
    CodecError,
    ImuSample,
    JointState,
    Message,
    RgbdFrame,
    decode,
    encode,
)


def _frame() -> RgbdFrame:
    return RgbdFrame(
        seq=7,
        stamp=1.5,
        camera="head_rgbd",
        intrinsics=CameraIntrinsics.from_fov(4, 3, 45.0),
        rgb=np.arange(36, dtype=np.uint8).reshape(3, 4, 3),
        depth=np.full((3, 4), 1.25, np.float32),
        T_world_camera=np.eye(4),
    )


def _imu() -> ImuSample:
    return ImuSample(
        angular_velocity=np.zeros(3),
        linear_acceleration=np.array([0, 0, 9.81]),
        orientation=np.array([1.0, 0, 0, 0]),
    )


def _raw(message: Message) -> dict:
    return msgpack.unpackb(encode(message))


def _kind(payload: bytes) -> str:
    with pytest.raises(CodecError) as info:
        decode(payload)
    assert str(info.value)  # a message that says something
    return info.value.kind


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=512))
def test_random_bytes_never_raise_anything_but_codec_error(payload):
    try:
        message = decode(payload)
    except CodecError as e:
        assert e.kind in {
            "malformed",
            "not_a_message",
            "unknown_schema",
            "wrong_version",
            "invalid",
        }
    else:  # astronomically unlikely, but then it must really be a message
        assert isinstance(message, Message)


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_corrupted_valid_payloads_never_raise_anything_but_codec_error(data):
    payload = bytearray(encode(_frame()))
    for _ in range(data.draw(st.integers(1, 8))):
        i = data.draw(st.integers(0, len(payload) - 1))
        payload[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(1, len(payload)))
    with contextlib.suppress(CodecError):
        decode(bytes(payload[:cut]))


def test_truncated_payload():
    assert _kind(encode(_frame())[:-10]) == "malformed"


def test_trailing_bytes():
    assert _kind(encode(_imu()) + b"\x00") == "malformed"


def test_not_a_map():
    assert _kind(msgpack.packb([1, 2, 3])) == "not_a_message"
    assert _kind(msgpack.packb({"seq": 1})) == "not_a_message"


def test_unknown_schema():
    raw = _raw(_imu())
    raw["schema"] = "ImuSampel"
    assert _kind(msgpack.packb(raw)) == "unknown_schema"


def test_wrong_version():
    raw = _raw(_imu())
    raw["version"] = 2
    with pytest.raises(CodecError, match="ImuSample version 2 is not the supported version 1"):
        decode(msgpack.packb(raw))


def test_array_bytes_not_matching_shape():
    raw = _raw(_frame())
    raw["depth"]["bytes"] = raw["depth"]["bytes"][:-4]
    with pytest.raises(CodecError, match=r"depth: .*truncated") as info:
        decode(msgpack.packb(raw))
    assert info.value.kind == "invalid"


def test_array_shape_against_the_declared_shape():
    raw = _raw(_frame())
    raw["T_world_camera"] = {"dtype": "float64", "shape": [3, 3], "bytes": bytes(72)}
    with pytest.raises(CodecError, match=r"T_world_camera: .*expected shape \[4, 4\]"):
        decode(msgpack.packb(raw))


def test_array_dtype_must_match():
    raw = _raw(_frame())
    raw["depth"] = {"dtype": "float64", "shape": [3, 4], "bytes": bytes(96)}
    with pytest.raises(CodecError, match=r"depth: .*float32"):
        decode(msgpack.packb(raw))


def test_arrays_on_the_wire_are_maps_not_lists():
    raw = _raw(_imu())
    raw["angular_velocity"] = [0.0, 0.0, 0.0]
    with pytest.raises(CodecError, match=r"angular_velocity: .*array map"):
        decode(msgpack.packb(raw))


def test_missing_field():
    raw = _raw(_imu())
    del raw["orientation"]
    with pytest.raises(CodecError, match="ImuSample: orientation: Field required"):
        decode(msgpack.packb(raw))


def test_unknown_field():
    raw = _raw(_imu())
    raw["temperature"] = 21.0
    with pytest.raises(CodecError, match="temperature: Extra inputs are not permitted"):
        decode(msgpack.packb(raw))


def test_wrong_field_type():
    raw = _raw(_imu())
    raw["seq"] = "seven"
    assert _kind(msgpack.packb(raw)) == "invalid"


def test_inconsistent_frame():
    raw = _raw(_frame())
    raw["intrinsics"]["width"] = 5
    with pytest.raises(CodecError, match="image is 4×3 but intrinsics say 5×3"):
        decode(msgpack.packb(raw))


def test_named_dimensions_must_agree():
    raw = _raw(JointState(names=["a", "b"], position=np.zeros(2), velocity=np.zeros(2)))
    raw["velocity"] = {"dtype": "float64", "shape": [3], "bytes": bytes(24)}
    with pytest.raises(CodecError, match="dimension 'n' is 2 in names but 3 in velocity"):
        decode(msgpack.packb(raw))


def test_non_rigid_pose():
    raw = _raw(_frame())
    raw["T_world_camera"]["bytes"] = (np.eye(4) * 2).tobytes()
    with pytest.raises(CodecError, match="T_world_camera"):
        decode(msgpack.packb(raw))


def test_expected_type():
    with pytest.raises(CodecError) as info:
        decode(encode(_imu()), RgbdFrame)
    assert info.value.kind == "unexpected_schema"
    assert decode(encode(_imu()), ImuSample) == _imu()


def test_peek_reads_a_frames_header_without_decoding_it():
    import numpy as np

    from schemas import CameraIntrinsics, RgbdFrame
    from schemas.codec import peek

    frame = RgbdFrame(seq=7, stamp=1.5, camera="head_rgbd",
                      intrinsics=CameraIntrinsics.from_fov(640, 480, 45.0),
                      depth=np.ones((480, 640), np.float32), T_world_camera=np.eye(4))  # fmt: skip
    payload = encode(frame)
    assert peek(payload, "camera", "seq") == {"camera": "head_rgbd", "seq": 7}
    assert peek(payload, "seq", "nothing") == {"seq": 7}  # what is not there is left out
    assert peek(b"\xc1 not msgpack", "seq") == {}
    assert peek(payload[:20], "camera", "seq") == {}  # cut before: nothing, no error


def test_peek_of_the_whole_payload_reads_fields_after_large_arrays():
    """``limit=None``: a field behind megabytes of arrays (a SceneModel's ``frame_seq`` after
    its primitives) is read, the arrays skipped; a field of another value kind comes back
    whole."""
    import numpy as np

    from schemas import CameraIntrinsics, RgbdFrame
    from schemas.codec import peek

    frame = RgbdFrame(seq=7, stamp=1.5, camera="head_rgbd",
                      intrinsics=CameraIntrinsics.from_fov(640, 480, 45.0),
                      depth=np.ones((480, 640), np.float32), T_world_camera=np.eye(4),
                      joint_names=["a", "b"], joint_positions=np.zeros(2))  # fmt: skip
    payload = encode(frame)
    assert "joint_names" not in peek(payload, "joint_names")  # beyond the first 512 bytes
    assert peek(payload, "joint_names", "seq", limit=None) == {"joint_names": ["a", "b"], "seq": 7}
