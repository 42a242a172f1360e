"""The utility of a view (thesis 4.3.3) and the strategies compared in 4.5: normalised
information gain and path cost (Eq. 4.10, 4.11), u(v) = IG̅(v) − λ·c̅(v) (Eq. 4.12, 4.13)."""

from __future__ import annotations

import numpy as np

STRATEGIES = ("utility", "occupancy", "random", "saliency")


def normalise(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Eq. 4.10 / 4.11: divided by the range over the (valid) candidates; the minimum is
    subtracted first, so the values span [0, 1] as the thesis states. Invalid ones get 0."""
    values = np.asarray(values, float)
    out = np.zeros(len(values))
    if not valid.any():
        return out
    lo, hi = values[valid].min(), values[valid].max()
    out[valid] = (values[valid] - lo) / (hi - lo) if hi > lo else 0.0
    return out


def utility(
    strategy: str,
    gain: np.ndarray,
    cost: np.ndarray,
    saliency: np.ndarray,
    lam: float,
    rng: np.random.Generator,
) -> np.ndarray:
    """u(v) per strategy; -inf where the view is unreachable (c = ∞).
    utility: IG̅ − λ·c̅ (Eq. 4.13); occupancy: IG̅ (Eq. 4.6 only); random: U(0, 1);
    saliency: s(v) of the top-down sampling (Eq. 4.5, 4.5.1)."""
    reachable = np.isfinite(cost)
    if strategy == "utility":
        u = normalise(gain, reachable) - lam * normalise(cost, reachable)
    elif strategy == "occupancy":
        u = normalise(gain, reachable)
    elif strategy == "random":
        u = rng.uniform(size=len(gain))
    elif strategy == "saliency":
        u = np.asarray(saliency, float).copy()
    else:
        raise ValueError(f"unknown strategy {strategy!r} (one of {', '.join(STRATEGIES)})")
    u[~reachable] = -np.inf
    return u
