"""The episode compares each view's predicted information gain with what it realised and
warns when the planner keeps predicting far more than it finds (a map that does not match
the scene: phantom geometry, a misregistered view)."""

from __future__ import annotations

import logging

from experiments.episode import Episode, ViewRecord


def _view(i: int, predicted: float, realised: float) -> ViewRecord:
    return ViewRecord(
        i, 1.0, 1.0, 1.0, 0, 0.0, 0.0, 1.0, 1.0, 0.1, [0, 0, 0],
        information_gain=predicted, realised_gain=realised,
    )  # fmt: skip


def test_two_views_in_a_row_under_a_tenth_of_their_prediction_warn(caplog):
    caplog.set_level(logging.WARNING, "avs.explore")
    views = [_view(0, 0.0, 9000.0), _view(1, 5000.0, 4000.0), _view(2, 6000.0, 400.0)]
    for n in range(1, 4):
        Episode._check_gain(views[:n])
    assert not caplog.records  # one poor view is no pattern
    views.append(_view(3, 3000.0, 100.0))
    Episode._check_gain(views)
    (record,) = caplog.records
    assert "views 2 and 3 realised 400 and 100 of a predicted 6000 and 3000" in record.message


def test_a_first_view_without_a_prediction_never_warns(caplog):
    caplog.set_level(logging.WARNING, "avs.explore")
    Episode._check_gain([_view(0, 0.0, 0.0), _view(1, 0.0, 0.0)])
    assert not caplog.records
