"""Key expressions are exactly SPEC §1's, and the exported JSON Schemas describe what is really
on the wire (checked by validating encoded messages against them)."""

from __future__ import annotations

import json

import jsonschema
import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from schemas import KEY_TABLE, REGISTRY, Keys, encode, spec_for
from schemas.export import export_json_schemas, json_schemas
from tests.strategies import model_strategy


def test_key_builders_match_the_spec_table():
    k = Keys("armar6")
    assert k.rgbd("head_rgbd") == "avs/armar6/sensors/rgbd/head_rgbd"
    assert k.imu() == "avs/armar6/sensors/imu"
    assert k.joints() == "avs/armar6/state/joints"
    assert k.base_state() == "avs/armar6/state/base"
    assert k.cmd_base() == "avs/armar6/cmd/base"
    assert k.cmd_head() == "avs/armar6/cmd/head"
    assert k.observation() == "avs/armar6/perception/observation"
    assert k.scene() == "avs/armar6/memory/scene"
    assert k.occupancy("stats") == "avs/armar6/memory/occupancy/stats"
    assert k.candidates() == "avs/armar6/nbv/candidates"
    assert k.next_view() == "avs/armar6/nbv/next_view"
    assert k.gaze_target() == "avs/armar6/gaze/target"
    assert k.egosphere() == "avs/armar6/gaze/egosphere"
    assert k.ground_truth() == "avs/armar6/sim/ground_truth"
    assert k.sim_control() == "avs/armar6/sim/control"
    assert k.alive("perception", "w1") == "avs/armar6/alive/perception/w1"
    assert k.metrics("nbv", "0") == "avs/armar6/metrics/nbv/0"
    assert Keys("armar3").imu() == "avs/armar3/sensors/imu"


@pytest.mark.parametrize("bad", ["", "a/b", "*", "x y", "$id", "**"])
def test_names_that_would_break_a_key_are_refused(bad):
    with pytest.raises(ValueError, match="not a valid key chunk"):
        Keys(bad)
    with pytest.raises(ValueError, match="not a valid key chunk"):
        Keys().occupancy(bad)


def test_every_key_row_names_registered_messages_and_matches_its_builder():
    for spec in KEY_TABLE:
        assert all(s in REGISTRY for s in spec.schemas), spec
    assert spec_for(Keys().imu()).express and spec_for(Keys().imu()).priority == "real_time"
    assert spec_for(Keys().rgbd("left_foveal")).congestion == "block"
    assert spec_for(Keys().occupancy("slice")).schemas == ("OccupancyStats", "OccupancySlice")
    assert spec_for("avs/armar6/unknown/key") is None


def _json_view(value):
    """What a JSON Schema validator can read of a decoded msgpack map: bytes become strings."""
    if isinstance(value, bytes):
        return "<bytes>"
    if isinstance(value, dict):
        return {k: _json_view(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_view(v) for v in value]
    return value


SCHEMAS = json_schemas()


@pytest.mark.parametrize("name", sorted(REGISTRY))
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_encoded_messages_validate_against_their_exported_schema(name, data):
    message = data.draw(model_strategy(REGISTRY[name]))
    wire = _json_view(msgpack.unpackb(encode(message)))
    jsonschema.validate(wire, SCHEMAS[name], cls=jsonschema.Draft202012Validator)


def test_exported_files_are_valid_json_schemas(tmp_path):
    paths = export_json_schemas(tmp_path)
    assert len(paths) == len(REGISTRY)
    for path in paths:
        schema = json.loads(path.read_text())
        jsonschema.Draft202012Validator.check_schema(schema)
        assert schema["properties"]["schema"] == {"const": path.stem, "description": "message name"}


def test_a_wrong_message_fails_its_schema():
    wire = _json_view(msgpack.unpackb(encode(REGISTRY["BaseGoal"](x=1, y=2, yaw=0))))
    wire["x"] = "one"
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(wire, SCHEMAS["BaseGoal"], cls=jsonschema.Draft202012Validator)
