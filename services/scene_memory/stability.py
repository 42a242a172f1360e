"""Support found in the fused geometry (thesis 3.2.2), where no single view saw the edge.

The thesis draws a support edge between two primitives in contact, from the one below the
separating plane to the one above; a primitive is stable when a chain of edges leads to the
ground ρ. Per view, a contact is often out of sight (a mug's foot behind its body, a chair
leg's top under the seat) or split between two segmentations of one object, so the memory
also reads the contacts off the *fused* primitives, to a fixpoint, each from something
already stable:

- **floor**: a primitive whose bottom reaches the floor (the lowest large level plane, when
  it lies near the world's ground z = 0) stands on it, wherever in the room: the floor runs
  under everything, seen or not;
- **level top**: its bottom lies on a stable level surface, at that surface's height *under
  it* (the plane's own equation: a 2 m table top tilted by 1° is 2 cm higher at one end than
  its box's centre), part of its base over the surface's footprint;
- **contact below**: ``contact_points`` of its points or more lie within ``contact`` of a
  stable primitive's points, and that contact is in its lower part (below its median height
  by ``contact_below``) with the supporter's points there not above it: the separating plane
  is below. A box beside a wall touches it at its side, not below, and stays unstable.

``bottom``: a low percentile of a primitive's points' z (one flying pixel does not lower it).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from schemas import Primitive

#: the curved kinds one round object may be fitted as, view by view
ROUND = frozenset({"sphere", "cylinder"})
#: points kept per primitive for the contact test (every k-th)
SAMPLE = 1500
#: how far under a body's base the space is probed for a support (m), and from how many of
#: its base points
BELOW = (0.05, 0.10, 0.15)
BASE_POINTS = 12
#: probes a view must hold evidence on (a surface in their cell, not hidden) to count
BELOW_EVIDENCE = 4


@dataclass(frozen=True)
class StabilityConfig:
    rest_tolerance: float = 0.03  # m: a bottom this close to a surface's height lies on it
    margin: float = 0.02  # m: a centre this far outside a surface's footprint is still over it
    contact: float = 0.025  # m: points this close touch
    contact_points: int = 5
    contact_below: float = 0.02  # m: a contact this far below the median height is under it
    floor_band: float = 0.04  # m: level planes this close to the lowest one are the floor ...
    floor_max: float = 0.3  # ... when it lies this low (the world's ground is z = 0)
    ground_area: float = 0.2  # m²: only level planes this large can be the floor
    level_deg: float = 15.0  # a surface within this of horizontal is level


@dataclass
class Body:
    """A fused primitive as stability sees it: its primitive, a sample of its points, their
    box, its bottom and top (2nd and 98th percentile of their z) and median height."""

    primitive: Primitive
    points: np.ndarray
    lo: np.ndarray = field(init=False)
    hi: np.ndarray = field(init=False)
    bottom: float = field(init=False)
    median_z: float = field(init=False)
    top: float = field(init=False)
    _tree: cKDTree | None = field(default=None, init=False, repr=False)
    _probes: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        p = self.points
        if len(p) > SAMPLE:
            p = self.points = p[:: int(np.ceil(len(p) / SAMPLE))]
        if len(p):
            self.lo, self.hi = p.min(axis=0), p.max(axis=0)
            self.bottom = float(np.percentile(p[:, 2], 2))
            self.median_z = float(np.median(p[:, 2]))
            self.top = float(np.percentile(p[:, 2], 98))
        else:
            reach = np.abs(self.primitive.obb.rotation) @ self.primitive.obb.extent / 2
            self.lo = self.primitive.obb.center - reach
            self.hi = self.primitive.obb.center + reach
            self.bottom = float(self.lo[2])
            self.median_z = float(self.primitive.obb.center[2])
            self.top = float(self.hi[2])

    @property
    def probes(self) -> np.ndarray:
        """Points in the space under the base (``BELOW`` under ``BASE_POINTS`` of its lowest
        points): where a supporter would be. A view that sees through them saw nothing
        there."""
        if self._probes is None:
            base = self.points[self.points[:, 2] <= self.bottom + 0.03] if len(self.points) else []
            if not len(base):
                base = np.array([[*self.primitive.obb.center[:2], self.bottom]])
            base = base[np.linspace(0, len(base) - 1, min(len(base), BASE_POINTS)).astype(int)]
            self._probes = np.concatenate([base - [0.0, 0.0, d] for d in BELOW])
        return self._probes

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree


def is_level(p: Primitive, c: StabilityConfig) -> bool:
    """A level plane (its normal within ``level_deg`` of z)."""
    m = p.model
    return m.kind == "plane" and abs(m.normal[2]) >= np.cos(np.radians(c.level_deg))


def plane_height(p: Primitive) -> float:
    """Height of a level plane under its box's centre (a large plane fitted 3° off level
    is 15 cm off at the world's origin)."""
    return _top_at(p, np.asarray(p.obb.center[:2]))


def floor_height(bodies: dict[int, Body], c: StabilityConfig) -> float | None:
    """The lowest large level plane's height, when it lies below ``floor_max``; else None
    (a table top is no floor)."""
    heights = [
        plane_height(b.primitive)
        for b in bodies.values()
        if is_level(b.primitive, c) and level_area(b.primitive, c.level_deg) >= c.ground_area
    ]
    lowest = min(heights, default=None)
    return lowest if lowest is not None and lowest < c.floor_max else None


def level_area(p: Primitive, level_deg: float = 15.0) -> float:
    """The area of a box's level face (the axes other than the one nearest vertical), 0
    when no axis lies within ``level_deg`` of vertical."""
    R, e = p.obb.rotation, p.obb.extent
    k = int(np.argmax(np.abs(R[2])))
    if abs(R[2, k]) < np.cos(np.radians(level_deg)):
        return 0.0
    return float(np.prod(np.delete(e, k)))


def _top_at(s: Primitive, xy: np.ndarray) -> float:
    """A level surface's height at ``xy``: the plane's equation, or a box's top face."""
    if s.model.kind == "plane":
        n = s.model.normal
        return float(-(n[0] * xy[0] + n[1] * xy[1] + s.model.d) / n[2])
    return float(s.obb.center[2] + np.abs(s.obb.rotation[2]) @ s.obb.extent / 2)


def _over(b: Body, s: Primitive, c: StabilityConfig) -> bool:
    """Is part of ``b``'s base (``contact_points`` of its points within ``rest_tolerance`` of
    its bottom) over ``s``'s footprint (its box's level axes, grown by ``margin``)? Partly on
    top is on top (Jia et al. 2013): a book at the back of a counter whose black top gave
    the sensor only its front edge."""
    R = s.obb.rotation
    k = int(np.argmax(np.abs(R[2])))
    axes = [m for m in range(3) if m != k]
    base = b.points[b.points[:, 2] <= b.bottom + c.rest_tolerance]
    if not len(base):
        base = np.asarray(b.primitive.obb.center)[None]
    local = (base - s.obb.center) @ R
    inside = np.all(np.abs(local[:, axes]) <= s.obb.extent[axes] / 2 + c.margin, axis=1)
    return int(inside.sum()) >= min(c.contact_points, len(base))


def _level_top(s: Primitive, c: StabilityConfig) -> bool:
    """A surface things can lie on: a level plane, or a box with a level face."""
    if s.model.kind == "plane":
        return is_level(s, c)
    if s.model.kind == "box":
        return float(np.max(np.abs(s.obb.rotation[2]))) >= np.cos(np.radians(c.level_deg))
    return False


def _touches_below(b: Body, s: Body, c: StabilityConfig) -> bool:
    """The contact rule: enough of ``b``'s points within ``contact`` of ``s``'s, in ``b``'s
    lower part, with ``s``'s points there not above them."""
    if s.lo[2] > b.median_z - c.contact_below + c.contact or s.hi[2] < b.bottom - c.contact:
        return False  # s lies wholly above b's lower part, or below its bottom
    q = b.points[
        np.all(b.points >= s.lo - c.contact, axis=1) & np.all(b.points <= s.hi + c.contact, axis=1)
    ]
    if len(q) < c.contact_points:
        return False
    d, k = s.tree.query(q, k=1, distance_upper_bound=c.contact)
    near = np.isfinite(d)
    if int(near.sum()) < c.contact_points:
        return False
    contact_z = float(np.median(q[near, 2]))
    if contact_z > b.median_z - c.contact_below:
        return False
    return float(np.median(s.points[k[near], 2])) <= contact_z + c.contact / 2


#: (resting body, supporter) → the rules' answer (rule, supporter; None), for as long as
#: both are unchanged
Touches = dict[tuple[int, int], tuple[Body, Body, tuple[str, int] | None]]


def settle(
    bodies: dict[int, Body],
    ground: set[int],
    supports: dict[int, list[int]],
    c: StabilityConfig,
    touches: Touches | None = None,
) -> tuple[set[int], dict[int, tuple[str, int | None]]]:
    """The stable bodies: ``ground``, what a chain of ``supports`` edges (supporter →
    supported) leads to from it, and what the rules above find resting on something stable,
    to a fixpoint; and of them, those a rule held (rule, supporter; None: the floor). One
    worklist: each body that becomes stable is asked once, for its edges and for the
    bodies near it that might rest on it. ``touches``: the contact rule's answers kept
    between calls (a model is rebuilt after every view, most primitives unchanged)."""
    touches = {} if touches is None else touches
    ids = list(bodies)
    row = {i: j for j, i in enumerate(ids)}
    lo = np.array([bodies[i].lo for i in ids]).reshape(-1, 3)
    hi = np.array([bodies[i].hi for i in ids]).reshape(-1, 3)
    grow = max(c.contact, c.rest_tolerance)
    stable = np.zeros(len(ids), bool)
    held: dict[int, tuple[str, int | None]] = {}
    queue = deque(i for i in ground if i in row)
    stable[[row[i] for i in queue]] = True
    floor = floor_height(bodies, c)
    if floor is not None:
        for i in ids:
            if not stable[row[i]] and bodies[i].bottom <= floor + c.rest_tolerance:
                held[i] = ("floor", None)
                stable[row[i]] = True
                queue.append(i)
    while queue:
        j = queue.popleft()
        for t in supports.get(j, []):
            if t in row and not stable[row[t]]:
                stable[row[t]] = True
                queue.append(t)
        r = row[j]
        near = np.flatnonzero(
            ~stable & np.all(lo <= hi[r] + grow, axis=1) & np.all(hi >= lo[r] - grow, axis=1)
        )
        for k in near.tolist():
            how = _rests_on(bodies[ids[k]], ids[k], bodies[j], j, c, touches)
            if how is not None:
                held[ids[k]] = how
                stable[k] = True
                queue.append(ids[k])
    return {i for i, on in zip(ids, stable.tolist(), strict=True) if on}, held


def _rests_on(
    b: Body, i: int, s: Body, j: int, c: StabilityConfig, touches: Touches
) -> tuple[str, int] | None:
    """Does ``b`` lie on ``s``'s level top, or touch it from above? (kept in ``touches``
    while both are unchanged)"""
    hit = touches.get((i, j))
    if hit is not None and hit[0] is b and hit[1] is s:
        return hit[2]
    how: tuple[str, int] | None = None
    centre = np.asarray(b.primitive.obb.center)
    if (
        _level_top(s.primitive, c)
        and abs(b.bottom - _top_at(s.primitive, centre[:2])) <= c.rest_tolerance
        and _over(b, s.primitive, c)
    ):
        how = ("level", j)
    elif len(s.points) and len(b.points) and _touches_below(b, s, c):
        how = ("contact", j)
    touches[i, j] = (b, s, how)
    return how
