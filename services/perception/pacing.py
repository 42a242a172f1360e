"""When a rate-capped worker takes its next frame, and which (issue 40: frame → model latency).

Taking the newest waiting frame when the worker's time comes hands it a frame up to one camera
period old (at 15 fps, 33 ms on average, 67 ms at worst), added to every observation's latency
for nothing. The ``Pacer`` keeps a fixed cadence of slots instead (``1/rate`` apart, never
closer on average) and takes, at each slot, the first frame that arrives from the slot on: its
age when taken is only its transport. A frame waiting from before the slot is taken only when
no fresher one comes within ``patience`` (one camera period, as estimated from the arrivals),
so the last frame of a recording is never lost, nor is a slow camera's frame held back longer.
A worker that overran its slot (a long frame) takes a frame that arrived since at once, and the
next slot is counted from then: no burst to catch up.
"""

from __future__ import annotations

import math


class Pacer:
    """Slots ``1/rate`` apart; a frame is *fresh* for a slot when it arrived at or after it."""

    def __init__(self, rate: float, smoothing: float = 0.2) -> None:
        if rate <= 0:
            raise ValueError(f"a pacer's rate must be > 0 frames a second, not {rate}")
        self.interval = 1.0 / rate
        self.slot = -math.inf  # the first frame is taken at once
        self.period = self.interval  # between arrivals, estimated (exponential average)
        self.smoothing = smoothing
        self._last_arrival: float | None = None

    def arrived(self, t: float) -> None:
        """A frame of this worker's arrived at ``t``: the camera period's estimate."""
        if self._last_arrival is not None and t > self._last_arrival:
            gap = min(t - self._last_arrival, 1.0)  # a paused stream does not make it a second
            self.period += self.smoothing * (gap - self.period)
        self._last_arrival = t

    def fresh(self, arrived: float) -> bool:
        """Whether a frame that arrived at ``arrived`` is one to take now (not one that waited
        from before the slot)."""
        return arrived >= self.slot

    def patience(self) -> float:
        """How long after the slot to wait for a fresh frame before taking a waiting one."""
        return min(1.5 * self.period, self.interval)

    def took(self, t: float) -> None:
        """A frame was taken at ``t``: the next slot, ``interval`` after this one (or after
        ``t``, when this worker was late; the first frame starts the cadence)."""
        first = not math.isfinite(self.slot)
        self.slot = t + self.interval if first else max(self.slot + self.interval, t)
