"""benchmarks/pipeline.py's bookkeeping: sim stamps put on this process's clock, a frame's
stages counted only where they happened, the per-frame latencies and the
environment avs up gets (the live run itself is the benchmark's to do)."""

from __future__ import annotations

import pytest

from benchmarks._loopback import user_environment
from benchmarks.pipeline import Frame, Ledger, SimClock, latencies


def test_a_sim_stamp_is_mapped_by_the_quickest_status_sample_near_it():
    clock = SimClock()
    clock.add(10.0, 100.000, 100.010)  # sim 10 s answered between 100.000 and 100.010
    clock.add(10.5, 100.499, 100.501)  # a quicker round trip: the better estimate
    clock.add(30.0, 120.100, 120.102)  # after a 0.1 s slip: far from the stamps below
    assert clock.to_monotonic(10.2) == pytest.approx(100.2)
    assert clock.to_monotonic(30.5) == pytest.approx(120.601)
    assert clock.rtt_ms() == pytest.approx(2.0)
    assert SimClock().to_monotonic(1.0) is None


def test_each_stage_counts_only_where_it_happened():
    """A frame mapped but never modelled is mapped, not semantic; one whose observation is in
    the model but whose depth the map never took is semantic, not mapped; an observation that
    never reached the model is neither."""
    clock = SimClock()
    clock.add(0.0, 50.0, 50.0)
    frames = [
        Frame(1, 1.0, observation=51.1, semantic=51.2, map=51.15),  # both
        Frame(2, 1.1, map=51.3),  # mapped, never observed
        Frame(3, 1.2, observation=51.3, map=51.25),  # observed and mapped, the model dropped it
        Frame(4, 1.3, observation=51.4, semantic=51.45),  # semantic, the map never took it
        Frame(5, 1.4, observation=51.5),  # observed only
    ]
    rows, per = latencies(frames, clock, 51.0, 52.0)
    assert [r["seq"] for r in rows] == [1, 2, 3, 4, 5]
    assert len(per["semantic"]) == 2 and len(per["map"]) == 3 and len(per["observation"]) == 4
    assert [r["semantic"] is not None for r in rows] == [True, False, False, True, False]
    assert [r["map"] is not None for r in rows] == [True, True, True, False, False]
    assert per["semantic"] == pytest.approx([200.0, 150.0])
    assert per["map"] == pytest.approx([150.0, 200.0, 50.0])


def test_latencies_per_frame_and_stage_within_the_run():
    clock = SimClock()
    clock.add(0.0, 50.0, 50.0)  # sim 0 is monotonic 50
    frames = [
        Frame(0, 0.5, observation=50.6),  # captured before the run: left out
        Frame(1, 1.0, observation=51.05, semantic=51.2, map=51.15),
        Frame(2, 1.2, map=51.3),
        Frame(3, 3.0, observation=53.1),  # captured after it: left out
    ]
    rows, per = latencies(frames, clock, 51.0, 52.0)
    assert [r["seq"] for r in rows] == [1, 2]
    assert rows[0]["observation"] == pytest.approx(50.0)
    assert rows[0]["semantic"] == pytest.approx(200.0)
    assert rows[0]["map"] == pytest.approx(150.0)
    assert rows[1]["observation"] is None and rows[1]["semantic"] is None
    assert rows[1]["map"] == pytest.approx(100.0)
    assert len(per["semantic"]) == 1 and len(per["map"]) == 2


def test_the_stack_starts_as_a_user_starts_it(monkeypatch):
    """No AVS_* setting of the benchmark's own environment reaches avs up."""
    monkeypatch.setenv("AVS_PERCEPTION_MAX_RATE", "0")
    monkeypatch.setenv("AVS_SIM_FPS", "5")
    env = user_environment()
    assert not [k for k in env if k.startswith("AVS_")]
    assert env["MUJOCO_GL"]


def test_a_model_that_names_a_frame_before_its_observation_came_is_timed_once_it_does():
    """A model names its frames by seq only (``fused_frames``); the capture stamp comes with
    the observation or the map's correction, whichever arrives."""
    ledger = Ledger()
    ledger.note("semantic", 5, None, 51.3)
    assert ledger.snapshot()[0].stamp is None
    ledger.note("observation", 5, 1.0, 51.2)
    clock = SimClock()
    clock.add(0.0, 50.0, 50.0)
    rows, per = latencies(ledger.snapshot(), clock, 51.0, 52.0)
    assert rows[0]["semantic"] == pytest.approx(300.0) and len(per["observation"]) == 1
