"""Fail-over in an episode: two scene memories on one data directory (one active, one standing
by); after the first view is fused the active one is killed with SIGKILL. The standby takes
over within 2 s, restoring what was written, and the episode goes on to the end."""

from __future__ import annotations

import signal
import time

import pytest

from experiments.episode import Episode, EpisodeConfig


@pytest.mark.timeout(600)
def test_the_episode_finishes_when_the_active_scene_memory_is_killed(tmp_path):
    took: list[float] = []

    def progress(i: int, n: int, record) -> None:
        if i != 1:
            return
        children = [c for c in episode.supervisor.children if c.info.name == "scene_memory"]
        (active,) = [c for c in children if c.active]
        (standby,) = [c for c in children if not c.active]
        active.process.send_signal(signal.SIGKILL)
        t0 = time.monotonic()
        while not standby.active and time.monotonic() - t0 < 10:
            time.sleep(0.02)
        took.append(time.monotonic() - t0)

    config = EpisodeConfig(scene="tabletop_occluded", views=3, voxel=0.02, out=tmp_path,
                           scale={"scene_memory": 2})  # fmt: skip
    episode = Episode(config, progress)
    views = episode.run().to_json()["views"]
    assert took and took[0] <= 2.0, took
    print(f"the standby took over {took[0]:.2f} s after the kill")
    assert len(views) == 3
    unknown = [v["unknown_voxels"] for v in views]
    assert unknown[2] < unknown[1] < unknown[0]  # the second view was kept, the third added
    assert views[-1]["support_f1"] >= 0.9
