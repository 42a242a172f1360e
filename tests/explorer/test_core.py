"""The exploration loop's state machine (services/explorer/core.py), driven with what a node
would sense: plain values on a clock of the test's choosing."""

from __future__ import annotations

import pytest

from services.explorer.core import Exploration, Halt, Limits, Look, Plan, Render, Sensed, View

TARGET = (1.0, 0.0, 0.8)


def view(step: int, cost: float = 4.0, **kw) -> View:
    return View(step=step, base=(0.5 * step, 0.0, 0.0), target=TARGET, information_gain=1e4,
                cost=cost, **kw)  # fmt: skip


class Robot:
    """What the node would see of a robot that does as it is told, on a clock."""

    def __init__(self) -> None:
        self.t, self.frame, self.fused, self.mapped, self.unknown = 0.0, 10, 10, 10, 1000
        self.goal, self.status, self.head_speed = "", "idle", 0.0

    def sensed(self, **kw) -> Sensed:
        s = Sensed(now=self.t, base=(0.0, 0.0, 0.0), goal_id=self.goal, goal_status=self.status,
                   head_speed=self.head_speed, frame_seq=self.frame, fused_seq=self.fused,
                   mapped_seq=self.mapped, unknown=self.unknown)  # fmt: skip
        for k, v in kw.items():
            setattr(s, k, v)
        return s


def run_view(x: Exploration, r: Robot, step: int, gain: int = 300) -> None:
    """Plan → move → settle → capture of one view, the robot obliging."""
    (plan,) = x.tick(r.sensed())
    assert isinstance(plan, Plan) and plan.step == step
    assert x.tick(r.sensed()) == []  # asked once, not again while it is answered
    assert x.planned(view(step), r.t) == [Look(TARGET)] and x.phase == "move"
    r.goal, r.status, r.head_speed = f"view-{step}", "moving", 0.5
    r.t += 2.0
    assert x.tick(r.sensed()) == [] and x.phase == "move"
    r.status = "reached"
    r.t += 1.0
    assert x.tick(r.sensed()) == [Look(TARGET)] and x.phase == "settle"
    r.t += 0.5
    assert x.tick(r.sensed()) == []  # the head still turning: not settled
    r.head_speed = 0.0
    x.tick(r.sensed())
    r.t += 0.35
    assert x.tick(r.sensed()) == [Render()] and x.phase == "capture"
    r.t += 0.2
    assert x.tick(r.sensed()) == []  # no frame after settling yet
    r.frame += 1
    assert x.tick(r.sensed()) == []  # a frame, not yet fused nor mapped
    r.fused = r.frame
    assert x.tick(r.sensed()) == []  # fused, not yet mapped
    r.mapped, r.unknown = r.frame, r.unknown - gain
    x.tick(r.sensed())


def test_an_episode_takes_its_views_and_says_why_it_stopped():
    x, r = Exploration(Limits(views=3)), Robot()
    x.start(r.t)
    for step in range(3):
        run_view(x, r, step)
        assert x.view == step + 1 and x.realised_gain == 300
    assert x.phase == "done" and x.reason == "max_views"
    assert len(x.visited) == 3


def test_the_planners_termination_ends_the_episode_with_its_reason():
    x, r = Exploration(Limits(views=5)), Robot()
    x.start(r.t)
    run_view(x, r, 0)
    (plan,) = x.tick(r.sensed())
    assert not plan.initial and len(plan.visited) == 1
    x.planned(View(step=1, terminate=True, reason="quality", detail="u below 5 %"), r.t)
    assert (x.phase, x.reason, x.detail, x.view) == ("done", "quality", "u below 5 %", 1)


def test_a_goal_not_reached_in_time_is_abandoned_and_excluded_from_the_next_plan():
    x, r = Exploration(Limits(views=5, move_margin_s=10.0)), Robot()
    x.start(r.t)
    x.tick(r.sensed())
    x.planned(view(0, cost=4.0), r.t)
    r.goal, r.status = "view-0", "moving"
    for k in range(10):  # drives along +y toward what stops it, sliding a little at the end
        r.t += 0.1
        assert x.tick(r.sensed(base=(0.2 + 0.01 * (k == 9), 0.05 * k, 0.0))) == []
    r.t += 16.9  # 2 × 4 s + 10 s: not yet (it stands pushing against it)
    assert x.tick(r.sensed(base=(0.21, 0.45, 0.0))) == []
    r.t += 0.2
    (halt,) = x.tick(r.sensed(base=(0.21, 0.45, 0.0)))
    assert isinstance(halt, Halt) and x.phase == "plan" and x.abandoned == 1
    (plan,) = x.tick(r.sensed())
    assert plan.step == 1 and plan.excluded.tolist() == [[0.0, 0.0, 0.0]]
    # where it got stuck and the way it came over its last 0.3 m: the next paths go round
    ((bx, by, dx, dy),) = plan.blocked.tolist()
    assert (bx, by) == (0.21, 0.45) and dx == pytest.approx(0.01 / 0.3, abs=0.01) and dy > 0.99
    assert x.view == 0  # an abandoned goal is no view
    # a platform that never moved is blocked toward its goal
    x.planned(view(2, cost=1.0), r.t)
    r.t += 12.5
    x.tick(r.sensed(base=(0.0, 0.0, 0.0)))
    (plan,) = x.tick(r.sensed())
    assert plan.blocked.tolist()[1] == [0.0, 0.0, 1.0, 0.0]


def test_goals_abandoned_in_a_row_end_the_episode():
    x, r = Exploration(Limits(views=5, max_abandoned=2)), Robot()
    x.start(r.t)
    for step in range(2):
        x.tick(r.sensed())
        x.planned(view(step), r.t)
        r.goal, r.status = f"view-{step}", "aborted"
        x.tick(r.sensed())
    assert (x.phase, x.reason) == ("done", "unreachable")


def test_a_planner_that_does_not_answer_is_asked_again():
    x, r = Exploration(Limits(retry_s=1.0)), Robot()
    x.start(r.t)
    x.tick(r.sensed())
    x.plan_failed("the planner did not answer", r.t)
    r.t += 0.5
    assert x.tick(r.sensed()) == [] and x.detail == "the planner did not answer"
    r.t += 0.6
    (plan,) = x.tick(r.sensed())
    assert plan.step == 0 and plan.initial


def test_a_frame_that_never_comes_times_out_with_a_named_reason():
    x, r = Exploration(Limits(capture_timeout_s=5.0)), Robot()
    x.start(r.t)
    x.tick(r.sensed())
    x.planned(view(0, moves=False), r.t)
    x.tick(r.sensed())  # no goal: settle
    x.tick(r.sensed())
    r.t += 0.4
    assert x.tick(r.sensed()) == [Render()]
    r.t += 5.1
    (halt,) = x.tick(r.sensed())
    assert (x.phase, x.reason) == ("done", "timeout") and isinstance(halt, Halt)
    assert x.detail.startswith("no frame came after settling")


def test_stop_halts_at_once_and_pause_resumes_by_planning_again():
    x, r = Exploration(), Robot()
    x.start(r.t)
    x.tick(r.sensed())
    x.planned(view(0), r.t)
    assert x.pause(r.t) == [Halt("paused")] and x.phase == "paused"
    assert x.tick(r.sensed()) == []
    x.resume(r.t)
    assert x.phase == "plan"
    (plan,) = x.tick(r.sensed())
    assert plan.step == 0
    assert x.stop(r.t) == [Halt("stopped")] and (x.phase, x.reason) == ("done", "stopped")
    assert x.planned(view(0), r.t) == []  # a late answer changes nothing
    with pytest.raises(ValueError, match="already exploring"):
        x2 = Exploration()
        x2.start(0.0)
        x2.start(0.0)
    x.start(r.t)  # a new episode after one is done
    assert x.episode == 2 and x.phase == "plan"


def test_a_head_that_never_stills_is_taken_after_the_settle_timeout():
    x, r = Exploration(Limits(settle_timeout_s=3.0)), Robot()
    x.start(r.t)
    x.tick(r.sensed())
    x.planned(view(0, moves=False), r.t)
    r.head_speed = 0.3
    x.tick(r.sensed())
    assert x.phase == "settle"
    r.t += 2.9
    assert x.tick(r.sensed()) == []
    r.t += 0.2
    assert x.tick(r.sensed()) == [Render()] and "not still" in x.detail


def test_hold_pauses_after_each_view_but_the_last_until_resumed():
    """``hold`` (an evaluator in lockstep): after a view the explorer waits, paused, with the
    view's frame named; resumed, it plans the next; after the last view it is done at once."""
    x, r = Exploration(Limits(views=2, hold=True)), Robot()
    x.start(r.t)
    run_view(x, r, 0)
    assert (x.phase, x.view, x.frame) == ("paused", 1, r.frame)
    assert x.tick(r.sensed()) == []  # held: no plan
    x.resume(r.t)
    assert x.phase == "plan" and x.detail == ""
    run_view(x, r, 1)
    assert (x.phase, x.reason, x.view) == ("done", "max_views", 2)
