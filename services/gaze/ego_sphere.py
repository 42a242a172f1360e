"""The sensory ego-sphere (thesis 5.1; Peters et al. 2009, Ruesch et al. 2008): 40,000
near-uniform gaze directions around the head, each holding a saliency value per source.

s_j = Σ_k w_k·s_j^k / Σ_k w_k (Eq. 5.1) over the values younger than the expiry (5 s), plus a
little noise; directions the head cannot reach are pruned; the maximum wins (winner-takes-all)
and is inhibited for a while once fixated (inhibition of return), so attention moves on.
Directions are unit vectors in the robot's platform frame, centred on the head."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

GOLDEN_ANGLE = np.pi * (3.0 - np.sqrt(5.0))


def fibonacci_sphere(n: int) -> np.ndarray:
    """n near-uniform unit vectors: the golden-angle spiral at equal-area heights."""
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    r = np.sqrt(1.0 - z * z)
    phi = GOLDEN_ANGLE * i
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


@dataclass
class Source:
    weight: float
    values: np.ndarray  # s_j^k per point
    stamps: np.ndarray  # when each value was set (-inf: never)
    distance: np.ndarray  # m: how far along its direction the salient thing is


class EgoSphere:
    def __init__(
        self,
        n: int = 40_000,
        expiry: float = 5.0,
        noise: float = 1e-3,
        inhibition_deg: float = 10.0,
        inhibition_s: float = 3.0,
        seed: int = 0,
    ) -> None:
        self.points = fibonacci_sphere(n)
        self.tree = cKDTree(self.points)
        self.expiry, self.noise = expiry, noise
        self.inhibition_deg, self.inhibition_s = inhibition_deg, inhibition_s
        self.sources: dict[str, Source] = {}
        self.reachable = np.ones(n, bool)
        self.inhibited_until = np.full(n, -np.inf)
        self.rng = np.random.default_rng(seed)

    def __len__(self) -> int:
        return len(self.points)

    def source(self, name: str, weight: float = 1.0) -> Source:
        """The source ``name`` (created with ``weight`` w_k the first time)."""
        if name not in self.sources:
            n = len(self.points)
            self.sources[name] = Source(
                weight, np.zeros(n, np.float32), np.full(n, -np.inf), np.full(n, 1.5, np.float32)
            )
        return self.sources[name]

    def near(self, direction: np.ndarray, radius_deg: float) -> np.ndarray:
        """Indices of the points within ``radius_deg`` of a direction."""
        d = np.asarray(direction, float)
        chord = 2.0 * np.sin(np.radians(radius_deg) / 2)
        return np.asarray(self.tree.query_ball_point(d / np.linalg.norm(d), chord), int)

    def add(
        self,
        name: str,
        direction: np.ndarray,
        value: float,
        stamp: float,
        spread_deg: float = 3.0,
        distance: float = 1.5,
        weight: float = 1.0,
    ) -> None:
        """Saliency ``value`` at a direction, spread over its neighbours with a Gaussian of
        ``spread_deg``, time-stamped ``stamp``; a fresher value replaces an older one."""
        src = self.source(name, weight)
        d = np.asarray(direction, float)
        d = d / np.linalg.norm(d)
        idx = self.near(d, 3 * spread_deg)
        if not len(idx):
            idx = np.array([self.tree.query(d)[1]])
        angle = np.degrees(np.arccos(np.clip(self.points[idx] @ d, -1.0, 1.0)))
        src.values[idx] = value * np.exp(-0.5 * (angle / spread_deg) ** 2)
        src.stamps[idx] = stamp
        src.distance[idx] = distance

    def saliency(self, now: float) -> np.ndarray:
        """s_j (Eq. 5.1) over the fresh values, with noise, 0 where unreachable."""
        n = len(self.points)
        total = np.zeros(n)
        weights = sum(s.weight for s in self.sources.values())
        for s in self.sources.values():
            fresh = now - s.stamps <= self.expiry
            total += np.where(fresh, s.weight * s.values, 0.0)
        if weights > 0:
            total /= weights
        total += self.noise * self.rng.random(n)
        return np.where(self.reachable, total, 0.0)

    def select(
        self, now: float, saliency: np.ndarray | None = None, floor: float | None = None
    ) -> int:
        """The winner: the reachable, not inhibited point of the largest saliency (−1 if every
        point is unreachable or inhibited, or with ``floor``, if the winner's saliency is not
        above it: noise alone does not call a saccade); ``saliency``: this instant's, if
        computed."""
        s = (self.saliency(now) if saliency is None else saliency).copy()
        s[(self.inhibited_until > now) | ~self.reachable] = -np.inf
        j = int(np.argmax(s))
        if not np.isfinite(s[j]) or (floor is not None and s[j] <= floor):
            return -1
        return j

    def distance(self, j: int, now: float) -> float:
        """How far the salient thing at point j is: from the freshest source that set it."""
        best, dist = -np.inf, 1.5
        for s in self.sources.values():
            if s.stamps[j] > best and now - s.stamps[j] <= self.expiry and s.values[j] > 0:
                best, dist = s.stamps[j], float(s.distance[j])
        return dist

    def inhibit(self, j: int, now: float) -> None:
        """Inhibition of return: the winner's neighbourhood cannot win for a while. (Its radius,
        10° by default, covers a value's spread in ``add``, 3σ of 3°: else the tails of the
        object just fixated would win next, and hold the gaze circling it.)"""
        self.inhibited_until[self.near(self.points[j], self.inhibition_deg)] = (
            now + self.inhibition_s
        )

    def prune(self, directions: np.ndarray, resolution_deg: float) -> None:
        """Keep only the points within ``resolution_deg`` of a direction the head's cameras
        can point along (samples of its joint space, e.g. from ``reachable_directions``)."""
        reach = np.zeros(len(self.points), bool)
        chord = 2.0 * np.sin(np.radians(resolution_deg) / 2)
        for hits in self.tree.query_ball_point(np.asarray(directions, float), chord):
            reach[hits] = True
        self.reachable = reach
