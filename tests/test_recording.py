"""MCAP recordings without Zenoh: what the writer puts in the file, as the ``mcap`` package's own
reader sees it; what replay reads back; files it refuses; the old format's conversion."""

from __future__ import annotations

import itertools
import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import msgpack
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from schemas import BaseGoal, BaseVelocity, decode, encode
from schemas.export import export_json_schemas
from services.common.playback import open_recording
from services.common.recording import RecordingError, RecordingWriter
from tests.conftest import ROOT
from tests.streams import imu_sample, rgbd_frame

IMU, RGBD, BASE = (
    "avs/armar6/sensors/imu",
    "avs/armar6/sensors/rgbd/head_rgbd",
    "avs/armar6/cmd/base",
)


def _write_from_threads(path: Path) -> dict[str, list[bytes]]:
    """300 IMU samples, 3 frames and 2 base commands of two types, from three threads at once."""
    sent = {
        IMU: [encode(imu_sample(i)) for i in range(300)],
        RGBD: [encode(rgbd_frame(i, 160, 120)) for i in range(3)],
        BASE: [
            encode(BaseGoal(seq=0, stamp=0.0, goal_id="g1", x=1.0, y=0.0, yaw=0.0)),
            encode(BaseVelocity(seq=1, stamp=0.1, v_x=0.1, v_y=0.0, v_yaw=0.0)),
        ],
    }
    writer = RecordingWriter(path, ["avs/armar6/**"])
    threads = [
        threading.Thread(target=lambda k=k: [writer.write(k, p) for p in sent[k]]) for k in sent
    ]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    writer.close()
    assert writer.dropped == 0 and writer.written == writer.received == 305
    return sent


def test_the_mcap_reader_sees_a_channel_per_key_with_its_json_schema(tmp_path):
    path = tmp_path / "run.mcap"
    sent = _write_from_threads(path)
    exported = tmp_path / "schemas"
    export_json_schemas(exported)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics.message_count == 305
        channels = {(c.topic, summary.schemas[c.schema_id].name) for c in summary.channels.values()}
        assert channels == {
            (IMU, "ImuSample"),
            (RGBD, "RgbdFrame"),
            (BASE, "BaseGoal"),
            (BASE, "BaseVelocity"),
        }
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            assert channel.message_encoding == "msgpack" and schema.encoding == "jsonschema"
            assert schema.data == (exported / f"{schema.name}.json").read_bytes()
        assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
        assert sum(c.uncompressed_size for c in summary.chunk_indexes) > os.path.getsize(path)
        got: dict[str, list[bytes]] = {k: [] for k in sent}
        times = []
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            got[channel.topic].append(message.data)
            times.append(message.log_time)
            assert schema.name == decode(message.data).SCHEMA
        assert got == sent  # each key's payloads byte for byte, in the order they came
        assert times == sorted(times)  # file order is log-time order
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        assert json.loads(metadata["avs"]["keys"]) == ["avs/armar6/**"]


def test_replay_reads_the_records_back_in_order_with_their_times(tmp_path):
    path = tmp_path / "run.mcap"
    sent = _write_from_threads(path)
    recording = open_recording(path)
    assert recording.keys == ["avs/armar6/**"] and recording.messages == 305
    assert recording.counts == {k: len(v) for k, v in sent.items()}
    records = list(recording.records)
    assert records[0].t == 0.0 and all(a.t <= b.t for a, b in itertools.pairwise(records))
    for key, payloads in sent.items():
        assert [r.payload for r in records if r.key == key] == payloads


def test_a_writer_that_falls_behind_drops_and_counts(tmp_path):
    path = tmp_path / "run.mcap"
    payload = os.urandom(1 << 20)  # 1 MB that zstd cannot shrink: writing takes a while
    writer = RecordingWriter(path, ["avs/x"], max_queued=2 << 20)
    accepted = sum(writer.write("avs/x", payload) for _ in range(200))
    writer.close()
    assert writer.dropped > 0 and accepted + writer.dropped == 200
    with open(path, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == accepted == writer.written


def test_files_that_are_no_avs_recording_are_refused_with_the_reason(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        open_recording(tmp_path / "missing.mcap")
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n" * 10)
    with pytest.raises(RecordingError, match=r"notes.mcap: not an MCAP file"):
        open_recording(text)
    cut = tmp_path / "cut.mcap"
    _write_from_threads(cut)
    cut.write_bytes(cut.read_bytes()[:-100])  # a recorder killed before it wrote the footer
    with pytest.raises(RecordingError, match=r"cut.mcap: an MCAP file cut short"):
        open_recording(cut)
    foreign = tmp_path / "camera.mcap"
    with open(foreign, "wb") as f:
        w = Writer(f)
        w.start()
        schema = w.register_schema("Image", "jsonschema", b"{}")
        channel = w.register_channel("/camera/image", "json", schema)
        w.add_message(channel, 1, b"{}", 1)
        w.finish()
    with pytest.raises(RecordingError, match=r"no AVS channels .* /camera/image \(json\)"):
        open_recording(foreign)


def _old_recording(path: Path, records: list[tuple[float, str, bytes]]) -> None:
    with open(path, "wb") as f:
        header = {"format": "avs-recording", "version": 1, "started": 1.7e9, "keys": ["avs/a/**"]}
        f.write(msgpack.packb(header))
        for t, key, payload in records:
            f.write(msgpack.packb({"t": t, "key": key, "payload": payload}, use_bin_type=True))


def test_an_old_recording_converts_with_one_command_and_replays_the_same(tmp_path):
    old, new = tmp_path / "run.avsrec", tmp_path / "run.mcap"
    records = [(0.5 + 0.01 * i, IMU, encode(imu_sample(i))) for i in range(50)]
    records.insert(5, (0.55, RGBD, encode(rgbd_frame(0, 160, 120))))
    _old_recording(old, records)
    with pytest.raises(RecordingError, match="avs record --convert"):
        open_recording(old)
    convert = [sys.executable, "-m", "avs.cli", "record", "--convert", str(old), "--out", str(new)]
    done = subprocess.run(convert, capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert done.returncode == 0 and f"converted 51 messages from {old}" in done.stderr
    recording = open_recording(new)
    assert recording.keys == ["avs/a/**"]
    replayed = [(r.t, r.key, r.payload) for r in recording.records]
    assert [(k, p) for _, k, p in replayed] == [(k, p) for _, k, p in records]
    assert [t for t, _, _ in replayed] == pytest.approx([t - 0.5 for t, _, _ in records], abs=1e-8)
