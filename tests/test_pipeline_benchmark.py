"""benchmarks/pipeline.py's bookkeeping: sim stamps put on this process's clock, a frame's
fused time, and the per-frame latencies (the live run itself is the benchmark's to do)."""

from __future__ import annotations

import pytest

from benchmarks.pipeline import Frame, SimClock, latencies


def test_a_sim_stamp_is_mapped_by_the_quickest_status_sample_near_it():
    clock = SimClock()
    clock.add(10.0, 100.000, 100.010)  # sim 10 s answered between 100.000 and 100.010
    clock.add(10.5, 100.499, 100.501)  # a quicker round trip: the better estimate
    clock.add(30.0, 120.100, 120.102)  # after a 0.1 s slip: far from the stamps below
    assert clock.to_monotonic(10.2) == pytest.approx(100.2)
    assert clock.to_monotonic(30.5) == pytest.approx(120.601)
    assert clock.rtt_ms() == pytest.approx(2.0)
    assert SimClock().to_monotonic(1.0) is None


def test_a_frame_is_fused_once_its_depth_is_in_the_map_and_its_observation_in_the_model():
    assert Frame(1, 0.0, observation=1.0, model=1.3).fused() is None  # not in the map
    assert Frame(2, 0.0, map=1.1).fused() == 1.1  # not observed: the map alone
    assert Frame(3, 0.0, observation=1.0, model=1.3, map=1.1).fused() == 1.3
    assert Frame(4, 0.0, observation=1.0, map=1.1).fused() == 1.1  # observation not fused


def test_latencies_per_frame_and_stage_within_the_run():
    clock = SimClock()
    clock.add(0.0, 50.0, 50.0)  # sim 0 is monotonic 50
    frames = [
        Frame(0, 0.5, observation=50.6),  # captured before the run: left out
        Frame(1, 1.0, observation=51.05, model=51.2, map=51.15),
        Frame(2, 1.2, map=51.3),
        Frame(3, 3.0, observation=53.1),  # captured after it: left out
    ]
    rows, per = latencies(frames, clock, 51.0, 52.0)
    assert [r["seq"] for r in rows] == [1, 2]
    assert rows[0]["observation"] == pytest.approx(50.0)
    assert rows[0]["fused"] == pytest.approx(200.0)
    assert rows[1]["observation"] is None and rows[1]["fused"] == pytest.approx(100.0)
    assert len(per["fused"]) == 2 and len(per["model"]) == 1
