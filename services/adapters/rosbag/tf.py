"""A small tf tree: the transforms of a bag's ``/tf`` and ``/tf_static``, looked up at any
time by interpolating each edge (translation linearly, rotation by slerp), like tf2's buffer.

Frame names are compared without a leading ``/`` (ROS 1 bags such as TUM RGB-D's write
``/world``, ROS 2 ``world``). Each frame has one parent; the root is the frame without one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from services.adapters.rosbag.convert import quaternion_matrix


class TfError(ValueError):
    """A frame that is not in the tree, or a tree that does not connect two frames."""


class ExtrapolationError(TfError):
    """A time outside what the bag recorded for an edge (beyond the tolerance)."""


def frame_name(name: str) -> str:
    return name.lstrip("/")


@dataclass
class _Edge:
    parent: str
    static: bool
    stamps: list[float] = field(default_factory=list)
    translations: list[tuple[float, float, float]] = field(default_factory=list)
    rotations: list[tuple[float, float, float, float]] = field(default_factory=list)  # x y z w
    _t: np.ndarray | None = None
    _p: np.ndarray | None = None
    _q: np.ndarray | None = None

    def freeze(self) -> None:
        order = np.argsort(self.stamps, kind="stable")
        self._t = np.asarray(self.stamps, float)[order]
        self._p = np.asarray(self.translations, float).reshape(-1, 3)[order]
        q = np.asarray(self.rotations, float).reshape(-1, 4)[order]
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        # one hemisphere along the sequence, so neighbours interpolate the short way
        for i in range(1, len(q)):
            if q[i] @ q[i - 1] < 0:
                q[i] = -q[i]
        self._q = q

    def at(self, t: float, tolerance: float) -> np.ndarray:
        if self._t is None:
            self.freeze()
        stamps, p, q = self._t, self._p, self._q
        if self.static or len(stamps) == 1:
            i = len(stamps) - 1
            if not self.static and abs(t - stamps[0]) > tolerance:
                raise ExtrapolationError(f"recorded at {stamps[0]:.3f} s only, not at {t:.3f} s")
            return _matrix(p[i], q[i])
        if t < stamps[0] - tolerance or t > stamps[-1] + tolerance:
            raise ExtrapolationError(
                f"{t:.3f} s is outside the recorded {stamps[0]:.3f}-{stamps[-1]:.3f} s"
            )
        j = int(np.searchsorted(stamps, t, side="right"))  # stamps[j - 1] <= t < stamps[j]
        if j == 0:
            return _matrix(p[0], q[0])
        if j >= len(stamps):
            return _matrix(p[-1], q[-1])
        t0, t1 = stamps[j - 1], stamps[j]
        s = 0.0 if t1 <= t0 else (t - t0) / (t1 - t0)
        return _matrix(p[j - 1] + s * (p[j] - p[j - 1]), slerp(q[j - 1], q[j], s))


def _matrix(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = quaternion_matrix(*q)
    T[:3, 3] = p
    return T


def slerp(q0: np.ndarray, q1: np.ndarray, s: float) -> np.ndarray:
    """Spherical interpolation of unit quaternions (any component order), s in [0, 1]."""
    if s <= 0.0:
        return q0
    if s >= 1.0:
        return q1
    d = float(np.clip(q0 @ q1, -1.0, 1.0))
    if d < 0:
        q1, d = -q1, -d
    if d > 0.9995:  # nearly parallel: normalised lerp
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = np.arccos(d)
    return (np.sin((1 - s) * theta) * q0 + np.sin(s * theta) * q1) / np.sin(theta)


class TransformTree:
    """Edges parent → child with their recorded samples; ``lookup`` composes a chain."""

    def __init__(self, tolerance: float = 0.05) -> None:
        #: how far (s) beyond an edge's first or last sample a lookup may reach
        self.tolerance = tolerance
        self.edges: dict[str, _Edge] = {}

    def add(
        self,
        parent: str,
        child: str,
        stamp: float,
        translation: tuple[float, float, float],
        rotation_xyzw: tuple[float, float, float, float],
        static: bool = False,
    ) -> None:
        """One transform T_parent_child at ``stamp`` (seconds)."""
        parent, child = frame_name(parent), frame_name(child)
        edge = self.edges.get(child)
        if edge is None:
            edge = self.edges[child] = _Edge(parent, static)
        elif edge.parent != parent:
            raise TfError(
                f"frame {child!r} has two parents in the bag: {edge.parent!r} and {parent!r}"
            )
        if static and not edge.static:  # a static transform wins over stray dynamic ones
            edge.static, edge.stamps, edge.translations, edge.rotations = True, [], [], []
        elif edge.static and not static:
            return
        if edge.static:  # keep the latest static transform only
            edge.stamps, edge.translations, edge.rotations = [], [], []
        edge.stamps.append(stamp)
        edge.translations.append(tuple(translation))
        edge.rotations.append(tuple(rotation_xyzw))
        edge._t = None

    @property
    def frames(self) -> set[str]:
        return set(self.edges) | {e.parent for e in self.edges.values()}

    @property
    def roots(self) -> set[str]:
        """The frames without a parent: one per separate tree."""
        return {e.parent for e in self.edges.values()} - set(self.edges)

    def chain(self, frame: str, target: str | None = None) -> list[str]:
        """The frames from ``frame`` up to ``target`` (default: the root), both included."""
        frame, target = frame_name(frame), frame_name(target) if target else None
        for name in (frame, target):
            if name is not None and name not in self.frames:
                raise TfError(
                    f"frame {name!r} is not in the bag's tf tree "
                    f"(frames: {', '.join(sorted(self.frames)) or 'none'})"
                )
        chain = [frame]
        while chain[-1] != target and chain[-1] in self.edges:
            parent = self.edges[chain[-1]].parent
            if parent in chain:
                raise TfError(f"the tf tree has a cycle through {parent!r}")
            chain.append(parent)
        if target is not None and chain[-1] != target:
            raise TfError(
                f"frame {target!r} is not above {frame!r} in the tf tree "
                f"(its chain: {' → '.join(reversed(chain))})"
            )
        return chain

    def root(self, frame: str) -> str:
        return self.chain(frame)[-1]

    def lookup(self, frame: str, t: float, target: str | None = None) -> np.ndarray:
        """T_target_frame at time ``t`` (s): the pose of ``frame`` in ``target`` (default: the
        root of its tree)."""
        chain = self.chain(frame, target)
        T = np.eye(4)
        for child in reversed(chain[:-1]):
            try:
                T = T @ self.edges[child].at(t, self.tolerance)
            except ExtrapolationError as e:
                raise ExtrapolationError(f"{self.edges[child].parent} → {child}: {e}") from None
        return T
