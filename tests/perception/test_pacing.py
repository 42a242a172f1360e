"""The rate-capped worker's pacing (services/perception/pacing.py), on a virtual clock: a
camera at 15 fps, a worker capped at 6 frames a second that takes ``work_s`` per frame."""

from __future__ import annotations

import numpy as np
import pytest

from services.perception.pacing import Pacer


def run(
    rate: float, camera_hz: float, work_s: float, seconds: float, pace: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Event simulation of node.py's worker loop: (times frames were taken, their ages then).
    ``pace=False``: the loop before the pacer (sleep ``1/rate`` from the last take, then the
    newest waiting frame)."""
    arrivals = np.arange(0.0, seconds, 1.0 / camera_hz) + 0.004  # + transport
    pacer, heard = Pacer(rate), -np.inf
    taken, ages, now, last, used = [], [], 0.0, -np.inf, -np.inf

    def newest_by(t: float) -> float | None:  # the frame waiting at t (a newer replaces it)
        got = arrivals[(arrivals <= t) & (arrivals > used)]
        return float(got[-1]) if len(got) else None

    while now < seconds - 1.0:
        if pace:
            now = max(now, pacer.slot)
            for a in arrivals[(arrivals <= now) & (arrivals > heard)]:
                pacer.arrived(float(a))
            heard = now
            waiting = newest_by(now)
            if waiting is None or not pacer.fresh(waiting):
                nxt = arrivals[arrivals > now]
                if len(nxt) and (waiting is None or nxt[0] - now <= pacer.patience()):
                    now = waiting = float(nxt[0])
                else:
                    now += pacer.patience()
            pacer.took(now)
        else:
            now = max(now, last + 1.0 / rate)
            waiting = newest_by(now)
            if waiting is None:
                waiting = now = float(arrivals[arrivals > now][0])
            last = now
        taken.append(now)
        ages.append(now - waiting)
        used = waiting
        now += work_s
    return np.array(taken), np.array(ages)


def test_frames_are_taken_fresh_at_the_capped_rate():
    """6 a second from a 15 fps camera: the rate holds (5.9-6.0 a second) and a frame is taken
    within 1 ms of its arrival, where taking the newest waiting one makes it 33 ms old on
    average (a camera period's half)."""
    taken, ages = run(6.0, 15.0, 0.08, 60.0)
    rate = len(taken) / 59.0  # the frames taken in the 59 s simulated
    assert 5.9 <= rate <= 6.05, rate
    assert np.max(ages) < 1e-3, ages.max()
    _, old = run(6.0, 15.0, 0.08, 60.0, pace=False)
    assert 0.02 < np.mean(old) < 0.045, np.mean(old)  # the loop it replaced: the falsifier


def test_a_worker_that_overran_takes_a_frame_at_once_and_never_bursts():
    """Frames that take longer than a slot (0.25 s against 1/6 s): one is taken as soon as the
    worker is free, every time (the rate falls to the worker's, 4 a second), never two closer
    than the work itself."""
    taken, ages = run(6.0, 15.0, 0.25, 30.0)
    gaps = np.diff(taken)
    assert np.all(gaps >= 0.25 - 1e-9) and np.median(gaps) < 0.25 + 1.0 / 15 + 1e-9, gaps
    assert np.max(ages) < 1.0 / 15 + 1e-9


def test_a_slow_camera_is_not_waited_for_longer_than_its_period():
    """A camera at 2 fps under a cap of 6: every frame is taken, each on its arrival."""
    taken, ages = run(6.0, 2.0, 0.05, 20.0)
    assert len(taken) >= 2 * 19 and np.max(ages) < 1e-3, (len(taken), ages.max())


def test_a_frame_that_waited_is_taken_when_no_fresher_one_comes():
    """The last frame of a recording arrived before the slot: after ``patience`` it is taken."""
    pacer = Pacer(6.0)
    for t in np.arange(0.0, 1.0, 1.0 / 15):
        pacer.arrived(float(t))
    pacer.took(0.8)
    pacer.took(0.95)  # the next slot: 0.8 + 1/6
    assert not pacer.fresh(0.95)  # arrived before the slot
    assert pacer.patience() == pytest.approx(1.5 / 15, rel=0.1)
    assert pacer.fresh(pacer.slot)


def test_a_rate_must_be_positive():
    with pytest.raises(ValueError, match="> 0"):
        Pacer(0.0)
