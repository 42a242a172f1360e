"""One next-best-view planning step (thesis Algorithm 5): sample views, give each its platform
pose (Eq. 4.2, 4.3) and head joints (IK, unreachable ones dropped), predict its information
gain (Eq. 4.6), plan its path and cost (Eq. 4.9), score it (Eq. 4.13 or another strategy) and
pick v̂ = argmax u(v). Pure: arrays and messages in, a PlanResult out."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from schemas import SceneModel
from schemas.planning import BLOCKED_RADIUS, EXCLUDED_RADIUS
from services.nbv import information_gain as ig
from services.nbv import topdown, view_sphere
from services.nbv.kinematics import HeadIK, HeadSolution
from services.nbv.path_cost import MARGIN, FloorMap, PathPlanner, path_cost
from services.nbv.utility import utility

#: where views exist but no path reaches any (the platform boxed in by floor it has not
#: seen), the robot looks around from where it stands: turned in place toward this many
#: directions, at a point this far away and this high (the floor around it, low furniture)
LOOK_DIRECTIONS, LOOK_DISTANCE, LOOK_HEIGHT = 12, 1.5, 0.4


def _timed(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """(fn(*args), the seconds it took)."""
    t0 = time.perf_counter()
    return fn(*args), time.perf_counter() - t0


def seed_ompl(seed: int) -> None:
    """OMPL seeds its random generators from the clock unless told otherwise: with a seed the
    planned paths, and so the episodes, repeat. It must come before OMPL's first generator."""
    from ompl import util as ou

    ou.RNG.setSeed(seed + 1)  # OMPL takes seeds > 0


@dataclass
class PlannerConfig:
    radius: float = 1.5  # view sphere r (4.1)
    sampling: str = "equidistant"
    strategy: str = "utility"
    lam: float = 0.5  # λ of Eq. 4.13
    lambda_s: float = 0.75  # Eq. 4.5
    lambda_quality: float = 0.05  # stop when the best view's predicted gain falls below this share
    max_views: int = 10
    k: int = 72  # equidistant grid step 2π/k (5°)
    samples: int = 200  # random sampling
    topdown_theta: float = math.radians(62)
    every: int = 30  # hierarchical IG: every 30th ray, ...
    best_k: int = 3  # ... then every ray for the best k
    ig_measure: str = "volume"  # or "rays" (Eq. 4.6 as printed): see information_gain
    max_range: float = 3.0
    intrinsics: tuple[int, int, float, float, float, float] = (
        640, 480, 583.06, 579.41, 319.5, 239.5,
    )  # fmt: skip
    vel_lin: float = 0.5
    vel_rot: float = 1.0
    footprint: float = 0.45
    height_tol: float = 0.05
    seed: int = 0
    roi: tuple[np.ndarray, np.ndarray] | None = None  # IG counts the unknown voxels in here
    workspace: tuple[np.ndarray, np.ndarray] | None = None  # (x, y) box the platform stays in


@dataclass
class Candidates:
    t: np.ndarray  # (n, 3) sphere points relative to their centre
    targets: np.ndarray  # (n, 3) the centre each view looks at
    poses: np.ndarray  # (n, 4, 4) T_world_camera reached by IK
    base: np.ndarray  # (n, 3)
    joints: list[dict[str, float]]
    saliency: np.ndarray


@dataclass
class PlanResult:
    candidates: Candidates
    gain: np.ndarray
    cost: np.ndarray
    utility: np.ndarray
    best: int | None
    path: np.ndarray | None
    terminate: bool
    reason: str
    timings_ms: dict[str, float] = field(default_factory=dict)
    detail: str = ""  # why, in words (no_candidates)
    looked_around: bool = False  # no view had a path: views turned in place were added


def _concat(*parts: Candidates) -> Candidates:
    """The candidates of ``parts`` in order, as one."""
    return Candidates(
        np.concatenate([p.t for p in parts]),
        np.concatenate([p.targets for p in parts]),
        np.concatenate([p.poses for p in parts]),
        np.concatenate([p.base for p in parts]),
        [j for p in parts for j in p.joints],
        np.concatenate([p.saliency for p in parts]),
    )


class Planner:
    def __init__(self, config: PlannerConfig, mjcf: Path, camera: str, robot: str) -> None:
        self.config = config
        self.ik = HeadIK(mjcf, camera, robot)
        self.rng = np.random.default_rng(config.seed)
        seed_ompl(config.seed)
        self.first_gain: float | None = None  # the best predicted gain of the first step
        # who computes the coarse gains of a step's candidates (the node fans them out)
        self.coarse_gains: Callable[[np.ndarray], np.ndarray] | None = None

    def sample(self, centre, scene: SceneModel | None, visited: np.ndarray, occupancy):
        """Sphere points (relative to the centre) and their saliency."""
        c = self.config
        if c.sampling == "random":
            t = view_sphere.random(c.samples, self.rng, c.radius)
        else:
            t = view_sphere.equidistant(c.k, c.radius)
        s = np.zeros(len(t))
        if c.sampling == "topdown" and scene is not None:
            pois = topdown.points_of_interest(scene, centre, visited[:, :2], c.lambda_s)
            t, s = topdown.saliency(t, pois, c.topdown_theta, c.radius, centre, *occupancy)
        return t, s

    def reachable_views(self, centre: np.ndarray, t: np.ndarray, s: np.ndarray) -> Candidates:
        """Eq. 4.2, 4.3 and the head IK; views without a solution are discarded."""
        todo, todo_bases = [], []
        lo, hi = self.ik.height_range()
        tol = self.config.height_tol
        for i, ti in enumerate(t):
            if not lo - tol <= centre[2] + ti[2] <= hi + tol:
                continue  # no torso height puts the camera there: skip the IK
            base = view_sphere.platform_pose(centre, ti)
            w = self.config.workspace
            if w is not None and not np.all((w[0][:2] <= base[:2]) & (base[:2] <= w[1][:2])):
                continue  # outside where the platform may go
            todo.append(i)
            todo_bases.append(base)
        targets = np.tile(np.asarray(centre, float), (len(todo), 1))
        heights = [centre[2] + t[i, 2] for i in todo]
        sols = self.ik.solve_many(todo_bases, targets, heights, height_tol=tol)
        keep, poses, bases, joints = [], [], [], []
        for i, base, sol in zip(todo, todo_bases, sols, strict=True):
            if sol is None:
                continue
            keep.append(i)
            poses.append(sol.T_world_camera)
            bases.append(base)
            joints.append(sol.joints)
        keep = np.array(keep, int)
        return Candidates(
            t[keep],
            np.tile(np.asarray(centre, float), (len(keep), 1)),
            np.array(poses).reshape(-1, 4, 4),
            np.array(bases).reshape(-1, 3),
            joints,
            s[keep],
        )

    def look(self, base: tuple[float, float, float], centre: np.ndarray) -> HeadSolution:
        """Head joints that aim the camera at the centre from where the robot stands (the first
        view): the torso as high as it goes, the neck by IK; the best aim the joints' ranges
        allow (its ``aim_error`` tells how far off that is)."""
        best = None
        for h in np.linspace(2.0, 0.8, 13):
            sol = self.ik.solve(base, centre, h, aim_tol=math.pi, height_tol=10.0)
            if sol is not None and (best is None or sol.aim_error < best.aim_error - 1e-4):
                best = sol
        return best

    def first_view(
        self, base: tuple[float, float, float], centre: np.ndarray, aim_tol: float = 0.02
    ) -> tuple[tuple[float, float, float], HeadSolution]:
        """The platform pose and head joints of the first view: from where the robot stands,
        looking at the centre; where the neck cannot turn that far (the robot faces away),
        the platform first turns in place toward the centre."""
        sol = self.look(base, centre)
        if sol.aim_error <= aim_tol:
            return base, sol
        x, y, _ = base
        turned = (x, y, math.atan2(centre[1] - y, centre[0] - x))
        return turned, self.look(turned, centre)

    def candidates(self, centres, scene, visited, occupancy) -> Candidates:
        """The reachable views of every view sphere (one per centre: the scene's centre or
        its points of interest, 4.1)."""
        return _concat(
            *(
                self.reachable_views(c, *self.sample(c, scene, visited, occupancy))
                for c in np.asarray(centres, float).reshape(-1, 3)
            )
        )

    def look_around(self, current: tuple[float, float, float]) -> Candidates:
        """Views from where the platform stands, turned in place toward ``LOOK_DIRECTIONS``
        points ``LOOK_DISTANCE`` around it, ``LOOK_HEIGHT`` up (the head as ``look`` aims
        it): what a robot does whose every view sphere lies beyond floor it has not seen
        (in the thesis's kitchen the table's view sphere is behind the robot's back)."""
        x, y, _ = current
        t, targets, poses, bases, joints = [], [], [], [], []
        for a in np.linspace(-math.pi, math.pi, LOOK_DIRECTIONS, endpoint=False):
            target = np.array([x + LOOK_DISTANCE * math.cos(a),
                               y + LOOK_DISTANCE * math.sin(a), LOOK_HEIGHT])  # fmt: skip
            base = (x, y, float(a))
            sol = self.look(base, target)
            if sol is None:
                continue
            t.append(sol.T_world_camera[:3, 3] - target)
            targets.append(target)
            poses.append(sol.T_world_camera)
            bases.append(base)
            joints.append(sol.joints)
        return Candidates(
            np.array(t).reshape(-1, 3), np.array(targets).reshape(-1, 3),
            np.array(poses).reshape(-1, 4, 4), np.array(bases).reshape(-1, 3), joints,
            np.zeros(len(t)),
        )  # fmt: skip

    @staticmethod
    def visible(cands: Candidates, occupancy) -> Candidates:
        """Only views that see their target: a single ray from the camera to the centre it looks
        at meets no occupied voxel (before the last 15 cm: the target lies on a surface). A
        view behind a known wall is no view of the scene, however much unknown space is
        around it."""
        sight = topdown.lines_of_sight(*occupancy, cands.targets, cands.poses[:, :3, 3], 0.15)
        keep = np.flatnonzero(sight).tolist()
        return Candidates(
            cands.t[keep],
            cands.targets[keep],
            cands.poses[keep],
            cands.base[keep],
            [cands.joints[i] for i in keep],
            cands.saliency[keep],
        )

    @staticmethod
    def why_no_candidates(
        planner: PathPlanner, current: tuple[float, float, float], sampled: tuple[int, int]
    ) -> str:
        """Why no view is left, in words: none the head reaches, none that sees its target,
        or the platform cannot move from where it stands (and how close the obstacle is)."""
        with_ik, visible = sampled
        if with_ik == 0:
            return "no view of the view sphere is reachable by the head's inverse kinematics"
        if visible == 0:
            return f"all {with_ik} views the head reaches look through known obstacles"
        x, y = current[:2]
        clearance = float(planner.floor.lookup(np.array([[x, y]]))[0])
        if clearance < planner.need:
            return (
                f"the platform at ({x:.2f}, {y:.2f}) is boxed in: an obstacle {clearance:.2f} m "
                f"from its centre, it needs {planner.need:.2f} m"
            )
        return f"none of the {visible} visible views has a collision-free path from here"

    def coarse(self, states, origin, voxel, poses: np.ndarray) -> np.ndarray:
        """The every-n-th-ray gains of ``poses`` on this map (a share of a step, for another
        planner that fans its candidates out)."""
        c = self.config
        gains, _ = ig.hierarchical(
            states, origin, voxel, poses, c.intrinsics, c.max_range, c.every, 0, c.roi,
            c.ig_measure,
        )  # fmt: skip
        return gains

    def warm_up(self) -> None:
        """Plan one step on a small made-up map: loads the compiled kernels (IG, visibility,
        floor map, segment checks), or compiles them on a machine's first run (seconds), before
        the node announces itself rather than in the middle of an episode's first step. The
        map has no obstacle between the robot and any view, so no path needs OMPL (whose random
        generator would move), and the planner's own state is put back."""
        voxel, n = 0.05, np.array([80, 80, 40])
        centre = np.array([0.0, 0.0, 0.9])
        origin = centre - n * voxel / 2
        origin[2] = 0.0
        states = np.full(n, ig.FREE, np.uint8)  # the dtype OccupancySlice carries
        k = np.floor((centre - origin) / voxel).astype(int)
        states[k[0] - 3 : k[0] + 3, k[1] - 3 : k[1] + 3, : k[2] - 2] = ig.OCCUPIED  # a table
        states[k[0] - 3 : k[0] + 3, k[1] - 3 : k[1] + 3, k[2] - 2 : k[2] + 4] = ig.UNKNOWN
        states.setflags(write=False)  # as decoded from a message: numba types it apart
        config, rng, first_gain = self.config, self.rng.bit_generator.state, self.first_gain
        fan_out, self.coarse_gains = self.coarse_gains, None
        self.config = replace(config, k=24, samples=20)  # a few views do (k=12 reaches none)
        try:
            # from the table's middle (the robot's own disc is cleared of obstacles) every
            # path is a straight line out: no RRT, whose draws would change the episode's
            self.plan(centre[None], None, states, origin, voxel, (centre[0], centre[1], 0.0),
                      np.zeros((0, 3)), 1)  # fmt: skip
        finally:
            self.config, self.rng.bit_generator.state = config, rng
            self.first_gain, self.coarse_gains = first_gain, fan_out

    def path_planner(
        self, states, origin, voxel, current, blocked: np.ndarray | None = None
    ) -> PathPlanner:
        """The platform's path planner on this map's floor, the robot's own footprint (and a
        margin) cleared: the map cannot have seen the floor under it. Where the platform got
        stuck (``blocked``: x, y, dx, dy) an obstacle of ``BLOCKED_RADIUS`` stands just ahead
        of its footprint, in the direction it drove (what stopped it touched the footprint
        there), so that the paths that follow go round it."""
        c = self.config
        ahead = c.footprint + MARGIN + BLOCKED_RADIUS + 0.03  # the stuck pose stays free
        bumps = [
            (x + ahead * dx, y + ahead * dy, BLOCKED_RADIUS)
            for x, y, dx, dy in (blocked if blocked is not None else np.zeros((0, 4)))
        ]
        floor = FloorMap.from_states(
            states,
            origin,
            voxel,
            keep_free=[(current[0], current[1], c.footprint + 0.1)],
            unseen_inside=c.roi,
            blocked=bumps,
        )
        return PathPlanner(floor, c.footprint, c.vel_lin, c.vel_rot)

    @staticmethod
    def path_costs(
        planner: PathPlanner, current, bases: np.ndarray
    ) -> tuple[np.ndarray, list[np.ndarray | None]]:
        """(c(v), the path) from ``current`` to each platform pose (Eq. 4.9; ∞ and None when
        unreachable)."""
        cost = np.full(len(bases), math.inf)
        paths: list[np.ndarray | None] = [None] * len(bases)
        for i, b in enumerate(bases):
            cost[i], paths[i] = planner.cost(np.array(current), b)
        return cost, paths

    def plan(
        self,
        centres: np.ndarray,
        scene: SceneModel | None,
        states: np.ndarray,
        origin: np.ndarray,
        voxel: float,
        current: tuple[float, float, float],
        visited: np.ndarray,
        step: int,
        excluded: np.ndarray | None = None,
        blocked: np.ndarray | None = None,
    ) -> PlanResult:
        """One planning step (Algorithm 5); candidates whose platform pose lies within
        ``EXCLUDED_RADIUS`` of an ``excluded`` one (goals the platform did not reach) are
        unreachable; paths go round where the platform got stuck (``blocked``,
        ``path_planner``)."""
        c = self.config
        times = {}
        t0 = time.perf_counter()
        occupancy = (states, origin, voxel)
        # A view whose platform pose is in collision, or in a free region the robot is not in,
        # has c = ∞ whatever its gain (every strategy drops it): IG is predicted for the others
        # only (in the booth, 1-2 views in 4), theirs stays 0. The floor map that tells, and then
        # the path costs (OMPL, Python), run on a second thread: the floor map beside the
        # sampling (head IK, Python on this thread), the path costs beside the skip map's build
        # and the ray casting (whose kernels release the GIL); they fill the cores' gaps instead
        # of following them; one thread, in order, as before: OMPL draws the same.
        planner: PathPlanner | None = None
        try:
            with ThreadPoolExecutor(1, thread_name_prefix="nbv-paths") as pool:
                floor_job = pool.submit(
                    _timed, self.path_planner, states, origin, voxel, current, blocked
                )
                reachable_by_ik = self.candidates(centres, scene, visited, occupancy)
                cands = self.visible(reachable_by_ik, occupancy)
                sampled = (len(reachable_by_ik.t), len(cands.t))
                times["sampling_ms"] = (time.perf_counter() - t0) * 1e3
                gain, cost = np.zeros(len(cands.t)), np.full(len(cands.t), math.inf)
                paths: list[np.ndarray | None] = [None] * len(cands.t)

                def maybe_reachable() -> np.ndarray:
                    """The candidates a path may reach (``PathPlanner.maybe_reachable``)."""
                    floor = floor_job.result()[0]  # done: the thread runs its jobs in order
                    return np.flatnonzero(floor.maybe_reachable(current, cands.base))

                maybe_job = pool.submit(_timed, maybe_reachable)
                t1 = time.perf_counter()
                skip = ig.SkipMap.build(states, origin, voxel, c.roi)
                (planner, floor_s), (maybe, maybe_s) = floor_job.result(), maybe_job.result()
                bases = cands.base[maybe]
                costs_job = pool.submit(_timed, self.path_costs, planner, current, bases)
                if len(maybe):
                    gain[maybe], _ = ig.hierarchical(
                        states, origin, voxel, cands.poses[maybe], c.intrinsics, c.max_range,
                        c.every, c.best_k, c.roi, c.ig_measure, self.coarse_gains, skip,
                    )  # fmt: skip
                times["information_gain_ms"] = (time.perf_counter() - t1) * 1e3
                (cost[maybe], found), costs_s = costs_job.result()
        finally:
            if planner is not None:
                planner.close()
        for i, path in zip(maybe, found, strict=True):
            paths[i] = path
        times["path_cost_ms"] = (floor_s + maybe_s + costs_s) * 1e3
        if excluded is not None and len(excluded) and len(cost):
            gap = np.linalg.norm(cands.base[:, None, :2] - excluded[None, :, :2], axis=2)
            cost[gap.min(axis=1) < EXCLUDED_RADIUS] = math.inf
        looked_around = False
        if sampled[1] and not np.isfinite(cost).any():
            # views, but no path to any: turn in place and look (the path a turn; Eq. 4.9)
            t2 = time.perf_counter()
            around = self.look_around(current)
            if len(around.t):
                looked_around = True
                g, _ = ig.hierarchical(
                    states, origin, voxel, around.poses, c.intrinsics, c.max_range, c.every,
                    c.best_k, c.roi, c.ig_measure,
                )  # fmt: skip
                turns = [np.array([current, b], float) for b in around.base]
                cands = _concat(cands, around)
                gain = np.concatenate([gain, g])
                cost = np.concatenate([cost, [path_cost(p, c.vel_lin, c.vel_rot) for p in turns]])
                paths = paths + turns
            times["look_around_ms"] = (time.perf_counter() - t2) * 1e3
        u = utility(c.strategy, gain, cost, cands.saliency, c.lam, self.rng)
        reachable = np.isfinite(cost)
        best = int(np.argmax(u)) if reachable.any() else None
        terminate, reason, detail = False, "", ""
        if best is None:
            terminate, reason = True, "no_candidates"
            detail = self.why_no_candidates(planner, current, sampled)
        else:
            if self.first_gain is None:
                self.first_gain = float(gain[reachable].max())
            if step >= c.max_views:
                terminate, reason = True, "max_views"
            elif gain[reachable].max() < c.lambda_quality * max(self.first_gain, 1.0):
                # no view left that would add much (the best one's gain, whichever strategy
                # picks: a random pick of a poor view is no reason to stop)
                terminate, reason = True, "quality"
        times["total_ms"] = (time.perf_counter() - t0) * 1e3
        return PlanResult(
            cands,
            gain,
            cost,
            u,
            best,
            paths[best] if best is not None else None,
            terminate,
            reason,
            times,
            detail,
            looked_around,
        )
