"""Planning with two nbv instances: the candidates' information gain is computed in shares by
both (nbv/gain/<instance>), one answers the plan, and the episode takes the same views as
with one instance."""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from experiments.episode import Episode, EpisodeConfig


def _views(workers: int, out: Path) -> list[dict]:
    config = EpisodeConfig(scene="tabletop_occluded", views=3, voxel=0.02, out=out,
                           scale={"nbv": workers})  # fmt: skip
    return Episode(config).run().to_json()["views"]


@pytest.mark.timeout(600)
def test_two_nbv_workers_choose_the_views_one_chooses(tmp_path):
    # both episodes at once, each with its own router and services (as `avs compare --jobs 2`)
    with ProcessPoolExecutor(2, mp_context=multiprocessing.get_context("spawn")) as pool:
        one, two = pool.map(_views, (1, 2), (tmp_path / "nbv1", tmp_path / "nbv2"))
    assert len(one) == len(two) >= 2
    for a, b in zip(one[1:], two[1:], strict=True):  # view 0 is the start view
        assert a["base"] == pytest.approx(b["base"], abs=1e-6)
        assert a["information_gain"] == pytest.approx(b["information_gain"], rel=1e-9)
        assert a["planning_workers"] == 1 and b["planning_workers"] == 2
