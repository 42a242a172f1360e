"""Path costs (thesis 4.3.2): a collision-free SE(2) path for the platform footprint against the
obstacles of the occupancy map projected to the floor, planned with OMPL's RRT-Connect, and its
cost c(v) = Σ max(‖Δp‖ / vel_lin, |Δα| / vel_rot) (Eq. 4.7-4.9), ∞ when unreachable.

Straight lines that are free need no planner; goals outside the start's free component (a
flood fill of the footprint's configuration space) are unreachable without asking it."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy import ndimage

from services.common.dda import dda_axis
from services.nbv.information_gain import FREE, FREE_8, OCCUPIED, OCCUPIED_8
from services.nbv.view_sphere import wrap

#: eight voxels' states in a word (``_any_set``): any but unknown
ANY_8 = FREE_8 | OCCUPIED_8


def path_cost(path: np.ndarray, vel_lin: float, vel_rot: float) -> float:
    """Eq. 4.8, 4.9 over a path of (x, y, α) rows; Δα wrapped to (−π, π] (Eq. 4.7)."""
    path = np.asarray(path, float)
    if len(path) < 2:
        return 0.0
    lin = np.linalg.norm(np.diff(path[:, :2], axis=0), axis=1) / vel_lin
    rot = np.abs(wrap(path[:-1, 2] - path[1:, 2])) / vel_rot
    return float(np.maximum(lin, rot).sum())


@njit(cache=True, nogil=True)
def segment_free(free: np.ndarray, ax: float, ay: float, bx: float, by: float) -> bool:
    """Grid traversal (Amanatides & Woo 1987) of the segment a→b, in cell units: True when
    every cell it passes through is ``free`` (cells outside the grid are unknown space, which
    is no obstacle). Exact, where sampling points along the segment can step over the corner
    of an obstacle."""
    nx, ny = free.shape
    i, j = math.floor(ax), math.floor(ay)
    # the segment's parameter t ∈ [0, 1] at the next cell boundary along x, y, and per cell
    si, tx, tdx = dda_axis(ax, bx - ax, 1.0, i)
    sj, ty, tdy = dda_axis(ay, by - ay, 1.0, j)
    i_end, j_end = math.floor(bx), math.floor(by)
    for _ in range(abs(i_end - i) + abs(j_end - j) + 1):
        if 0 <= i < nx and 0 <= j < ny and not free[i, j]:
            return False
        if tx < ty:
            tx += tdx
            i += si
        else:
            ty += tdy
            j += sj
    return True


@njit(cache=True, nogil=True, inline="always")
def _any_set(flat, words, start, end, mask, mask_8):
    """Whether a byte of ``flat[start:end]`` has a bit of ``mask``: byte by byte to a word
    boundary, then eight at a time (``words``: ``flat`` as uint64, ``mask_8`` eight ``mask``)."""
    k = start
    while k < end and k & 7:
        if flat[k] & mask:
            return True
        k += 1
    while k + 8 <= end:
        if words[k >> 3] & mask_8:
            return True
        k += 8
    while k < end:
        if flat[k] & mask:
            return True
        k += 1
    return False


@njit(cache=True, nogil=True, parallel=True)
def _columns(states, words, k0, k1, kh):
    """Per floor cell of the states (C order; ``words``: the same, flat, as uint64): whether
    its column holds an occupied voxel in the layers [k0, k1), and whether its layers [k0, kh)
    are all unknown (0), eight voxels at a time (numpy's ``any`` and ``all`` made a temporary
    of the map's size each; a byte loop took 11 ms on a 1 cm map)."""
    nx, ny, nz = states.shape
    flat = states.reshape(-1)
    obstacle = np.zeros((nx, ny), np.bool_)
    unseen = np.zeros((nx, ny), np.bool_)
    for i in prange(nx):
        for j in range(ny):
            base = (i * ny + j) * nz
            lo = base + min(k0, nz)
            obstacle[i, j] = _any_set(flat, words, lo, base + min(k1, nz), OCCUPIED, OCCUPIED_8)
            unseen[i, j] = not _any_set(flat, words, lo, base + min(kh, nz), FREE | OCCUPIED, ANY_8)
    return obstacle, unseen


@dataclass
class FloorMap:
    """Clearance (m) from every floor cell to the nearest obstacle voxel between ``z_range``."""

    origin: np.ndarray  # (x, y) of cell (0, 0)'s corner
    cell: float
    clearance: np.ndarray  # (nx, ny) metres

    @classmethod
    def from_states(
        cls,
        states: np.ndarray,
        origin: np.ndarray,
        voxel: float,
        z_range: tuple[float, float] = (0.05, 2.0),
        keep_free: list[tuple[float, float, float]] = (),
        unseen_inside: tuple[np.ndarray, np.ndarray] | None = None,
        unseen_height: float = 1.3,
        blocked: list[tuple[float, float, float]] = (),
    ) -> FloorMap:
        """Obstacles: occupied voxels between the heights ``z_range``; discs (x, y, radius) in
        ``blocked`` are obstacles whatever the map says (where the platform got stuck on
        something no camera saw), and discs in ``keep_free`` are cleared (the robot's own
        body, seen by its camera: it stands where it stands). Inside the xy box
        ``unseen_inside`` (the scene's roi) a column never seen up to ``unseen_height`` is an
        obstacle too: the robot does not drive through the part of the scene it has not looked
        at (furniture may stand there); outside it, unknown floor is taken as free."""
        k0 = max(0, int((z_range[0] - origin[2]) / voxel))
        k1 = max(k0, math.ceil((z_range[1] - origin[2]) / voxel))
        kh = max(k0 + 1, math.ceil((unseen_height - origin[2]) / voxel))
        states = np.require(states, np.uint8, "C")
        flat = states.reshape(-1)
        obstacle, unseen = _columns(states, flat[: len(flat) - len(flat) % 8].view(np.uint64),
                                    k0, k1, kh)  # fmt: skip
        if unseen_inside is not None:
            lo = np.floor((np.asarray(unseen_inside[0])[:2] - origin[:2]) / voxel).astype(int)
            hi = np.ceil((np.asarray(unseen_inside[1])[:2] - origin[:2]) / voxel).astype(int)
            lo, hi = np.clip(lo, 0, obstacle.shape), np.clip(hi, 0, obstacle.shape)
            box = np.zeros_like(obstacle)
            box[lo[0] : hi[0], lo[1] : hi[1]] = True
            obstacle |= unseen & box
        xs = origin[0] + (np.arange(obstacle.shape[0]) + 0.5) * voxel
        ys = origin[1] + (np.arange(obstacle.shape[1]) + 0.5) * voxel
        for x, y, r in blocked:
            obstacle |= (xs[:, None] - x) ** 2 + (ys[None, :] - y) ** 2 <= r * r
        for x, y, r in keep_free:
            obstacle &= (xs[:, None] - x) ** 2 + (ys[None, :] - y) ** 2 > r * r
        if obstacle.any():
            clearance = ndimage.distance_transform_edt(~obstacle) * voxel
        else:
            clearance = np.full(obstacle.shape, np.inf)
        return cls(np.asarray(origin[:2], float), voxel, clearance)

    def lookup(self, xy: np.ndarray) -> np.ndarray:
        """Clearance at points (n, 2); ∞ outside the map (unknown space, no obstacle: the map
        is made to cover everywhere the platform may need to go)."""
        k = np.floor((np.asarray(xy, float).reshape(-1, 2) - self.origin) / self.cell).astype(int)
        inside = np.all((k >= 0) & (k < self.clearance.shape), axis=1)
        out = np.full(len(k), np.inf)
        out[inside] = self.clearance[k[inside, 0], k[inside, 1]]
        return out


@functools.cache
def _exact_motions():
    """OMPL's MotionValidator with an exact check, made on first use (OMPL loads lazily)."""
    from ompl import base as ob

    class ExactMotions(ob.MotionValidator):
        """A motion is valid when every cell its footprint centre crosses is (the footprint is
        a disc: yaw does not matter), one traversal per motion instead of OMPL's
        state-by-state sampling, which can cut a corner. Holds the grid, not the planner: a
        reference back to it would make a cycle through OMPL that Python cannot collect."""

        def __init__(self, si, free: np.ndarray, origin: np.ndarray, cell: float) -> None:
            super().__init__(si)
            self.free, self.cell = free, float(cell)
            # Python floats (the same doubles): numpy scalars make each of the ~11k calls of a
            # planning step slower for nothing
            self.ox, self.oy = float(origin[0]), float(origin[1])

        def checkMotion(self, s1, s2, *last_valid) -> bool:
            ox, oy, c = self.ox, self.oy, self.cell
            return segment_free(
                self.free, (s1.getX() - ox) / c, (s1.getY() - oy) / c,
                (s2.getX() - ox) / c, (s2.getY() - oy) / c,
            )  # fmt: skip

    return ExactMotions


#: m: the clearance a path keeps beyond the footprint's radius
MARGIN = 0.05


class PathPlanner:
    """Platform paths on one FloorMap for a footprint of ``radius`` (+ ``margin``)."""

    def __init__(
        self,
        floor: FloorMap,
        radius: float,
        vel_lin: float,
        vel_rot: float,
        margin: float = MARGIN,
        time_limit: float = 0.2,
    ) -> None:
        self.floor, self.vel_lin, self.vel_rot = floor, vel_lin, vel_rot
        self.need = radius + margin
        self.time_limit = time_limit
        self.free = floor.clearance >= self.need
        self.labels, _ = ndimage.label(self.free)
        self._si = self._space = self._motions = None
        #: ``_decided`` per (start, goal): ``maybe_reachable`` asks it of every candidate and
        #: ``plan`` again of each (70 µs a pair, Python)
        self._decisions: dict[tuple[float, ...], tuple[bool, np.ndarray | None]] = {}

    def valid(self, xy: np.ndarray) -> np.ndarray:
        return self.floor.lookup(xy) >= self.need

    def close(self) -> None:
        """Release the OMPL objects, users before what they use (the motion validator and
        the space information before the state space): left to the interpreter's exit, they
        go in no particular order and nanobind reports each as leaked. ``plan`` remakes them."""
        self._motions = None
        self._si = None
        self._space = None

    def _segment_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Every floor cell the footprint's centre crosses from a to b is free (exact)."""
        o, cell = self.floor.origin, self.floor.cell
        return segment_free(
            self.free, (a[0] - o[0]) / cell, (a[1] - o[1]) / cell,
            (b[0] - o[0]) / cell, (b[1] - o[1]) / cell,
        )  # fmt: skip

    def _label(self, xy) -> int:
        """The free component of the cell under ``xy`` (0: not free; -1: outside the map)."""
        k = np.floor((np.asarray(xy[:2]) - self.floor.origin) / self.floor.cell).astype(int)
        if np.any(k < 0) or np.any(k >= self.labels.shape):
            return -1
        return int(self.labels[k[0], k[1]])

    def _decided(self, start: np.ndarray, goal: np.ndarray) -> tuple[bool, np.ndarray | None]:
        """What ``plan`` knows without a search: (True, the straight path) when the line is
        free, (True, None) when the goal cannot be reached (its cell not free, the start boxed
        in, or the two in different free components), (False, None) when only RRT can tell."""
        key = (*start.tolist(), *goal.tolist())
        if key not in self._decisions:
            self._decisions[key] = self._decide(start, goal)
        return self._decisions[key]

    def _decide(self, start: np.ndarray, goal: np.ndarray) -> tuple[bool, np.ndarray | None]:
        if not self.valid(goal[None, :2])[0]:
            return True, None
        if self._segment_free(start, goal):
            return True, np.stack([start, goal])
        if not self.valid(start[None, :2])[0]:
            return True, None  # boxed in: the caller clears its own footprint first
        a, b = self._label(start), self._label(goal)
        if a >= 0 and b >= 0 and a != b:
            return True, None  # two free components of the map, no way round outside it
        return False, None

    def plan(self, start, goal) -> np.ndarray | None:
        """Waypoints (x, y, α) from start to goal, or None when the goal is unreachable."""
        start, goal = np.asarray(start, float), np.asarray(goal, float)
        decided, path = self._decided(start, goal)
        return path if decided else self._rrt(start, goal)

    def maybe_reachable(self, start, goals: np.ndarray) -> np.ndarray:
        """Per goal (n, 3): False where ``plan`` would return None without a search (so c = ∞
        for certain), True where a path is known or a search may find one."""
        start = np.asarray(start, float)
        out = np.ones(len(goals), bool)
        for i, goal in enumerate(np.asarray(goals, float)):
            decided, path = self._decided(start, goal)
            out[i] = not decided or path is not None
        return out

    def _space_information(self):
        from ompl import base as ob
        from ompl import util as ou

        if self._si is None:
            ou.setLogLevel(ou.LOG_WARN)  # not a line per query
            space = ob.SE2StateSpace()
            bounds = ob.RealVectorBounds(2)
            lo = self.floor.origin
            hi = lo + np.array(self.floor.clearance.shape) * self.floor.cell
            for i in range(2):
                bounds.setLow(i, float(lo[i]))
                bounds.setHigh(i, float(hi[i]))
            space.setBounds(bounds)
            si = ob.SpaceInformation(space)
            free, origin, cell = self.free, self.floor.origin, self.floor.cell
            nx, ny = free.shape

            ox, oy, cell = float(origin[0]), float(origin[1]), float(cell)

            def valid(state) -> bool:
                i = int((state.getX() - ox) / cell)
                j = int((state.getY() - oy) / cell)
                return bool(not (0 <= i < nx and 0 <= j < ny) or free[i, j])

            si.setStateValidityChecker(valid)
            ExactMotions = _exact_motions()
            # kept alive here: OMPL holds no reference
            self._motions = ExactMotions(si, free, origin, cell)
            si.setMotionValidator(self._motions)
            si.setup()
            self._si, self._space = si, space
        return self._si

    def _rrt(self, start: np.ndarray, goal: np.ndarray) -> np.ndarray | None:
        from ompl import base as ob
        from ompl import geometric as og

        si = self._space_information()
        s, g = self._space.allocState(), self._space.allocState()
        for state, p in ((s, start), (g, goal)):
            state.setX(float(p[0]))
            state.setY(float(p[1]))
            state.setYaw(float(p[2]))
        pdef = ob.ProblemDefinition(si)
        pdef.setStartAndGoalStates(s, g)
        planner = og.RRTConnect(si)
        planner.setProblemDefinition(pdef)
        planner.setup()
        waypoints = None
        if str(planner.solve(self.time_limit)) == "Exact solution":
            path = pdef.getSolutionPath()
            simplifier = og.PathSimplifier(si)
            simplifier.reduceVertices(path)
            simplifier.ropeShortcutPath(path)
            waypoints = np.array([[q.getX(), q.getY(), q.getYaw()] for q in path.getStates()])
            del simplifier, path
        planner.clear()
        del planner, pdef, s, g  # the planner before what it plans in (see close)
        return waypoints

    def cost(self, start, goal) -> tuple[float, np.ndarray | None]:
        """(c(v), the path); (∞, None) when unreachable (Eq. 4.9)."""
        path = self.plan(start, goal)
        if path is None:
            return math.inf, None
        return path_cost(path, self.vel_lin, self.vel_rot), path
