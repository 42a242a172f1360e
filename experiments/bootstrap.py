"""Medians over seeds with their uncertainty: the percentile bootstrap of the median (Efron &
Tibshirani 1993, ch. 13), and which orderings of strategies the intervals support.

``median_interval(values)`` resamples the values with replacement (``resamples`` times, from a
fixed random stream, so a figure is repeatable), takes each resample's median and returns the
sample's median with the central ``confidence`` share of the resampled medians. An ordering
"a < b" of two strategies on a metric is *supported* when a's interval lies wholly below b's
(they do not overlap) and both rest on at least ``MIN_VALUES`` values, otherwise it is not
resolved at that many seeds. Non-overlap of two 95 % intervals is a conservative test (it
rejects equal medians less often than 5 %); it is what a reader of the intervals can check by
eye. Below 5 values the interval falls well short of its level: a resampled median never
leaves [min, max], which misses the true median in 2 · (1/2)ⁿ of samples (25 % of samples of
3). Pure numpy."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import combinations

import numpy as np

#: resamples of a bootstrap: 10,000 puts the interval's ends within ~1 % of their limit
RESAMPLES = 10_000
#: the bootstrap's random stream (fixed: the same runs give the same intervals)
SEED = 0
#: the fewest values an interval needs for an ordering to rest on it (see above)
MIN_VALUES = 5


@dataclass(frozen=True)
class Interval:
    """A sample's median and its bootstrap interval, over ``n`` values."""

    median: float
    lo: float
    hi: float
    n: int

    def overlaps(self, other: Interval) -> bool:
        return self.lo <= other.hi and other.lo <= self.hi

    def to_json(self) -> dict:
        return {"median": self.median, "ci95": [self.lo, self.hi], "n": self.n}


def median_interval(
    values: Sequence[float],
    confidence: float = 0.95,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> Interval:
    """The median of ``values`` and the percentile bootstrap interval of it."""
    x = np.asarray(values, float)
    if x.ndim != 1 or len(x) == 0:
        raise ValueError("median_interval needs a non-empty list of values")
    rng = np.random.default_rng(seed)
    medians = np.median(x[rng.integers(0, len(x), (resamples, len(x)))], axis=1)
    tail = 100 * (1 - confidence) / 2
    lo, hi = np.percentile(medians, [tail, 100 - tail])
    return Interval(float(np.median(x)), float(lo), float(hi), len(x))


@dataclass(frozen=True)
class Ordering:
    """``better`` has the better median of a metric than ``worse`` (or the same); ``supported``:
    their intervals do not overlap and each has at least ``MIN_VALUES`` values."""

    metric: str
    better: str
    worse: str
    supported: bool

    def to_json(self) -> dict:
        return {"metric": self.metric, "better": self.better, "worse": self.worse,
                "supported": self.supported}  # fmt: skip


def orderings(
    metric: str, intervals: Mapping[str, Interval], higher_is_better: bool = False
) -> list[Ordering]:
    """Every pair of strategies on one metric, the better median first (ties: the names'
    order), each with whether the intervals support it."""
    sign = -1.0 if higher_is_better else 1.0
    ranked = sorted(intervals, key=lambda k: (sign * intervals[k].median, k))
    out = []
    for a, b in combinations(ranked, 2):
        ia, ib = intervals[a], intervals[b]
        enough = min(ia.n, ib.n) >= MIN_VALUES
        out.append(Ordering(metric, a, b, enough and not ia.overlaps(ib)))
    return out
