"""``avs record`` and ``avs sim --replay`` as processes over Zenoh: messages on two keys, spaced
apart, come back in the same order across keys with the recorded gaps (scaled by --speed); a
file that is no AVS recording stops the replay at once with the reason."""

from __future__ import annotations

import itertools
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from schemas import Keys, encode
from tests.conftest import avs_env, wait_for
from tests.sim.test_sim_node import start_sim
from tests.streams import imu_sample, rgbd_frame

KEYS = Keys()
GAPS = (0.0, 0.1, 0.1, 0.3, 0.05, 0.2, 0.1, 0.15)  # seconds before each message
SPEED = 2.0


def _listen(client: zenoh.Session) -> tuple[list[tuple[float, str, bytes]], list]:
    """Everything on sensors/**, with the time it came; the subscriber is returned too (keep it)."""
    got: list[tuple[float, str, bytes]] = []
    lock = threading.Lock()

    def on(sample: zenoh.Sample) -> None:
        with lock:
            got.append((time.monotonic(), str(sample.key_expr), sample.payload.to_bytes()))

    return got, [client.declare_subscriber("avs/armar6/sensors/**", on)]


def test_replay_keeps_the_order_across_keys_and_the_recorded_timing(
    client, router, procs, tmp_path
):
    out = tmp_path / "timed.mcap"
    recorder = procs.python(
        ["-m", "avs.cli", "record", "sensors/**", "--out", str(out)],
        env=avs_env(router),
        stderr=subprocess.PIPE,
        text=True,
    )
    keys = [KEYS.imu() if i % 3 else KEYS.rgbd("head_rgbd") for i in range(len(GAPS))]
    pubs = {k: client.declare_publisher(k) for k in set(keys)}
    wait_for(lambda: all(p.matching_status.matching for p in pubs.values()), 30, "the recorder")
    sent = []
    for i, (gap, key) in enumerate(zip(GAPS, keys, strict=True)):
        time.sleep(gap)  # the pace of the stream under test, not a synchronisation
        payload = encode(rgbd_frame(i, 80, 60) if "rgbd" in key else imu_sample(i))
        pubs[key].put(payload)
        sent.append((time.monotonic(), key, payload))
    time.sleep(0.3)  # let the last sample reach the recorder before it stops
    recorder.send_signal(2)
    assert recorder.wait(30) == 0
    assert f"recorded {len(GAPS)} messages on 2 channels" in recorder.stderr.read()

    got, subs = _listen(client)
    replay = start_sim(procs, router, "--replay", str(out), "--speed", str(SPEED))
    assert replay.wait(60) == 0
    assert [(k, p) for _, k, p in got] == [(k, p) for _, k, p in sent]
    sent_gaps = [b[0] - a[0] for a, b in itertools.pairwise(sent)]
    got_gaps = [b[0] - a[0] for a, b in itertools.pairwise(got)]
    assert got_gaps == pytest.approx([g / SPEED for g in sent_gaps], abs=0.04)
    assert got[-1][0] - got[0][0] == pytest.approx(sum(GAPS[1:]) / SPEED, abs=0.06)
    for s in subs:
        s.undeclare()


def test_a_file_that_is_no_recording_stops_the_replay_with_the_reason(router, tmp_path):
    bad = tmp_path / "notes.mcap"
    bad.write_text("hello\n")
    replay = subprocess.run(
        [sys.executable, "-m", "services.sim", "--replay", str(bad)],
        env=avs_env(router),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert replay.returncode == 2
    assert f"{bad}: not an MCAP file" in replay.stderr
