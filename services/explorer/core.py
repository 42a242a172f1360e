"""The exploration loop (thesis Algorithm 5 in a loop, 4.5) as a state machine on any clock.

    idle → plan → move → settle → capture → plan … → done          (paused beside them)

- **plan**: ask the planner for the next-best view (``Plan``; the first one only turns the head
  toward the roi from where the robot stands). A planner that does not answer (restarting) is
  asked again every ``retry_s``; its termination (u(v̂) below quality, no candidate) ends the
  episode with its reason.
- **move**: the planner drives the platform (its BaseGoal); the core fixates the view's target
  (``Look``: the gaze holds it while the platform drives). A goal the platform does not reach
  within twice its estimated time plus ``move_margin_s`` (or that it aborts) is abandoned: the
  platform is stopped (``Halt``), the next plan excludes that pose, and its paths go round
  where the platform got stuck (``blocked``: its position and the direction it came from;
  something the map does not hold stopped it there); ``max_abandoned`` in a row end the
  episode.
- **settle**: platform and head still (below ``base_still``, ``head_still``) for
  ``settle_hold_s``, measured from odometry and joint states; after ``settle_timeout_s`` the
  view is taken anyway (said in ``detail``).
- **capture**: a frame taken after settling (``Render`` in lockstep; in wall clock the camera
  streams), its observation in the scene model and its depth taken by the map (integrated, or
  skipped as a keyframe the map already has); then the view is counted, its realised gain (the
  roi's unknown voxels it made known) noted, and the view limit decides. Nothing within
  ``capture_timeout_s`` ends the episode with a named reason.

The core never waits and never talks: the node feeds it what it sensed (``Sensed``, on its
clock: sim time in lockstep, monotonic time on the wall clock) and the planner's replies, and
carries out the actions it returns (``Plan``, ``Look``, ``Halt``, ``Render``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

#: m: the platform's direction of travel where it got stuck is that of its last this many m
APPROACH_M = 0.3


@dataclass(frozen=True)
class Limits:
    views: int = 10
    head_still: float = 0.05  # rad/s: the head has arrived when every joint moves slower
    base_still: float = 0.03  # m/s and rad/s: the platform likewise
    settle_hold_s: float = 0.3  # … for this long
    settle_timeout_s: float = 8.0
    move_margin_s: float = 10.0
    capture_timeout_s: float = 30.0
    retry_s: float = 1.0
    max_abandoned: int = 3
    #: after each view but the last, wait (paused) until resumed: an evaluator in lockstep
    #: scores the view while the sim stands still
    hold: bool = False


@dataclass
class Sensed:
    """What the node knows now (None: not heard of yet)."""

    now: float
    base: tuple[float, float, float] | None = None  # odometry (x, y, yaw)
    base_speed: float = 0.0  # max(|v|, |ω|)
    goal_id: str = ""
    goal_status: str = "idle"
    head_speed: float | None = None  # max |q̇| over the head joints
    frame_seq: int | None = None  # the newest frame of the camera
    fused_seq: int | None = None  # the newest frame whose observation the scene model holds
    mapped_seq: int | None = None  # the newest frame the map took (integrated or skipped)
    unknown: int | None = None  # unknown voxels in the roi, as the map says now


@dataclass(frozen=True)
class View:
    """What the core needs of the planner's NextBestView."""

    step: int
    terminate: bool = False
    reason: str = ""
    detail: str = ""
    base: tuple[float, float, float] = (0.0, 0.0, 0.0)
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    information_gain: float = 0.0
    cost: float = 0.0
    moves: bool = True  # the planner sent a BaseGoal ``view-<step>``


@dataclass(frozen=True)
class Plan:
    step: int
    initial: bool
    visited: np.ndarray  # (k, 3) platform poses of the views taken
    excluded: np.ndarray  # (k, 3) goals abandoned
    blocked: np.ndarray  # (k, 4) where the platform got stuck, and the direction it drove


@dataclass(frozen=True)
class Look:
    target: tuple[float, float, float]


@dataclass(frozen=True)
class Halt:
    reason: str


@dataclass(frozen=True)
class Render:
    pass


Action = Plan | Look | Halt | Render


@dataclass
class Exploration:
    limits: Limits = field(default_factory=Limits)
    phase: str = "idle"
    episode: int = 0
    views: int = 0  # the episode's limit
    view: int = 0  # views taken
    step: int = 0  # the planner's step (a new one after an abandoned goal)
    current: View | None = None
    reason: str = ""
    detail: str = ""
    realised_gain: float = 0.0
    unknown: int | None = None
    abandoned: int = 0
    frame: int | None = None  # the frame of the last view taken
    version: int = 0  # bumped on every change worth a status
    visited: list[tuple[float, float, float]] = field(default_factory=list)
    excluded: list[tuple[float, float, float]] = field(default_factory=list)
    blocked: list[tuple[float, float, float, float]] = field(default_factory=list)
    _track: list[tuple[float, float]] = field(default_factory=list)  # (x, y) while moving
    _asked: bool = False
    _retry_at: float = -math.inf
    _deadline: float = math.inf
    _since: float | None = None
    _began: float = 0.0
    _after: int | None = None  # the newest frame when settled: the view's is newer
    _frame: int | None = None
    _unknown_before: int | None = None
    _in_a_row: int = 0
    _resume: str = ""

    # -- commands -----------------------------------------------------------------------------

    def start(self, now: float, views: int = 0) -> list[Action]:
        if self.phase not in ("idle", "done"):
            raise ValueError(f"already exploring (phase {self.phase}): stop it first")
        self.episode += 1
        self.views = views or self.limits.views
        self.view = self.step = self.abandoned = self._in_a_row = 0
        self.current, self.reason, self.detail = None, "", ""
        self.realised_gain, self.visited, self.excluded, self.blocked = 0.0, [], [], []
        self.frame = None
        self._to("plan", now)
        return []

    def pause(self, now: float) -> list[Action]:
        if self.phase in ("idle", "done", "paused"):
            return []
        self._resume = self.phase
        self._to("paused", now)
        return [Halt("paused")]

    def resume(self, now: float) -> list[Action]:
        if self.phase != "paused":
            return []
        # a move the halt interrupted is planned again from where the platform stands
        back = self._resume if self._resume in ("capture", "plan") else "plan"
        self.detail = ""
        self._to(back, now)
        return []

    def stop(self, now: float, reason: str = "stopped", detail: str = "") -> list[Action]:
        if self.phase in ("idle", "done"):
            return []
        self._finish(reason, detail, now)
        return [Halt(reason)]

    # -- the planner --------------------------------------------------------------------------

    def planned(self, view: View, now: float) -> list[Action]:
        """The planner's answer to the ``Plan`` asked."""
        self._asked = False
        if self.phase != "plan":  # paused or stopped meanwhile: the answer is dropped
            return []
        if view.terminate:
            self._finish(view.reason or "planner", view.detail, now)
            return []
        self.current, self._track = view, []
        self._deadline = now + 2 * view.cost + self.limits.move_margin_s
        self._unknown_before = self.unknown
        self._to("move", now)
        return [Look(view.target)]

    def plan_failed(self, error: str, now: float) -> list[Action]:
        """No answer (the planner restarting): asked again after ``retry_s``."""
        self._asked = False
        self._retry_at = now + self.limits.retry_s
        if self.detail != error:
            self.detail = error
            self.version += 1
        return []

    # -- the clock ----------------------------------------------------------------------------

    def tick(self, s: Sensed) -> list[Action]:
        if s.unknown is not None:
            self.unknown = s.unknown
        if self.phase == "plan":
            if self._asked or s.now < self._retry_at:
                return []
            self._asked = True
            return [
                Plan(
                    self.step, self.view == 0 and self.step == 0,
                    np.array(self.visited, float).reshape(-1, 3),
                    np.array(self.excluded, float).reshape(-1, 3),
                    np.array(self.blocked, float).reshape(-1, 4),
                )
            ]  # fmt: skip
        if self.phase == "move":
            return self._move(s)
        if self.phase == "settle":
            return self._settle(s)
        if self.phase == "capture":
            return self._capture(s)
        return []

    def _move(self, s: Sensed) -> list[Action]:
        v = self.current
        goal = f"view-{v.step}" if v.moves else ""
        if s.base is not None and (
            not self._track or math.dist(self._track[-1], s.base[:2]) > 0.02
        ):
            self._track = [*self._track[-499:], (s.base[0], s.base[1])]
        if goal and s.goal_id == goal and s.goal_status == "aborted":
            return self._abandon(s, "the platform aborted the goal")
        if not goal or (s.goal_id == goal and s.goal_status == "reached"):
            self._since, self._after = None, s.frame_seq
            self._to("settle", s.now)
            return [Look(v.target)]
        if s.now > self._deadline:
            return self._abandon(s, f"not reached within {self._deadline - self._began:.0f} s")
        return []

    def _abandon(self, s: Sensed, why: str) -> list[Action]:
        """Give the goal up: not planned again (``excluded``), and where the platform stands
        after driving toward it for longer than it should have, something the map does not
        hold is in its way (``blocked``: the platform's position and the direction of its
        last ``APPROACH_M`` of travel, or the goal's direction when it never moved so far)."""
        now = s.now
        self.abandoned += 1
        self._in_a_row += 1
        self.excluded.append(self.current.base)
        if s.base is not None:
            here = (s.base[0], s.base[1])
            back = [p for p in self._track if math.dist(p, here) >= APPROACH_M]
            if back:  # the way it came
                d = (here[0] - back[-1][0], here[1] - back[-1][1])
            else:  # the way it was to go
                d = (self.current.base[0] - here[0], self.current.base[1] - here[1])
            far = math.hypot(*d)
            if far > 1e-6:
                self.blocked.append((*here, d[0] / far, d[1] / far))
        self.step += 1
        if self._in_a_row >= self.limits.max_abandoned:
            self._finish("unreachable", f"{self._in_a_row} goals in a row abandoned: {why}", now)
        else:
            self.detail = f"goal {self.current.step} abandoned: {why}"
            self._to("plan", now)
        return [Halt(f"goal {self.current.step} abandoned")]

    def _settle(self, s: Sensed) -> list[Action]:
        lim = self.limits
        still = s.head_speed is not None and s.head_speed < lim.head_still
        still = still and s.base_speed < lim.base_still
        if still:
            self._since = s.now if self._since is None else self._since
        else:
            self._since = None
        settled = self._since is not None and s.now - self._since >= lim.settle_hold_s
        if settled or s.now - self._began > lim.settle_timeout_s:
            self.detail = "" if settled else f"not still after {lim.settle_timeout_s:g} s"
            self._after, self._frame = s.frame_seq, None
            self._to("capture", s.now)
            return [Render()]
        return []

    def _capture(self, s: Sensed) -> list[Action]:
        newer = s.frame_seq is not None and (self._after is None or s.frame_seq > self._after)
        if self._frame is None and newer:
            self._frame = s.frame_seq
        f = self._frame
        fused = f is not None and s.fused_seq is not None and s.fused_seq >= f
        mapped = f is not None and s.mapped_seq is not None and s.mapped_seq >= f
        if fused and mapped and s.unknown is not None:
            return self._taken(s)
        if s.now - self._began > self.limits.capture_timeout_s:
            waited = (
                "no frame came after settling" if f is None
                else f"frame {f} never reached the scene model" if not fused
                else f"frame {f} never reached the map" if not mapped
                else "no occupancy statistics"
            )  # fmt: skip
            self._finish("timeout", f"{waited} within {self.limits.capture_timeout_s:g} s", s.now)
            return [Halt("timeout")]
        return []

    def _taken(self, s: Sensed) -> list[Action]:
        self.view += 1
        self._in_a_row = 0
        before = self._unknown_before
        self.realised_gain = float(before - s.unknown) if before is not None else 0.0
        if s.base is not None:
            self.visited.append(tuple(map(float, s.base)))
        self.step += 1
        self.frame = self._frame
        if self.view >= self.views:
            self._finish("max_views", f"{self.view} views taken", s.now)
        elif self.limits.hold:
            self._resume, self.detail = "plan", f"view {self.view} taken: held until resumed"
            self._to("paused", s.now)
        else:
            self._to("plan", s.now)
        return []

    # -- bookkeeping --------------------------------------------------------------------------

    def _to(self, phase: str, now: float) -> None:
        self.phase, self._began = phase, now
        self._retry_at = -math.inf
        self.version += 1

    def _finish(self, reason: str, detail: str, now: float) -> None:
        self.reason, self.detail = reason, detail
        self._asked = False
        self._to("done", now)
