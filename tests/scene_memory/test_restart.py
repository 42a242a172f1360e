"""A scene memory with a 35 MB map serves again within 2 s of kill -9: ``avs up`` runs it with a
hot standby, which on the active's death loads the snapshot (checked data, not pickle) and the
bounded journal and declares itself."""

from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from schemas import Keys, OccupancyStats, decode
from services.scene_memory.memory import MemoryConfig, SceneMemory
from services.scene_memory.persistence import Store
from tests.conftest import avs_env, liveliness_tokens, wait_for

KEYS = Keys()


def stats(client) -> OccupancyStats | None:
    for r in client.get(KEYS.occupancy("stats"), timeout=1):
        if r.ok:
            return decode(r.ok.payload.to_bytes(), OccupancyStats)
    return None


@pytest.mark.timeout(300)
def test_a_35_mb_map_is_served_within_2_s_of_a_kill_9(client, router, procs, tmp_path):
    memory = SceneMemory(MemoryConfig())  # the service's default map: 5 × 5 × 2.25 m at 1 cm
    L = memory.occupancy.L
    L[:, :, :56] = -200  # 14 M voxels known (free): what a long run leaves behind
    L[200:260, 200:260, 40:56] = 300  # and some occupied
    memory.occupancy.L = L
    Store(tmp_path).snapshot(memory, 1)
    size = (tmp_path / "snapshot.avs").stat().st_size
    assert 30e6 < size < 45e6, size
    expected = memory.occupancy.counts()

    def start(instance: str):
        args = ["-m", "services.scene_memory", "--instance", instance,
                "--data-dir", str(tmp_path)]  # fmt: skip
        return procs.python(args, env=avs_env(router))

    active = start("m-a")
    wait_for(lambda: KEYS.alive("scene_memory", "m-a") in liveliness_tokens(client, KEYS.alive()),
             60, "the active instance")  # fmt: skip
    start("m-b")
    standby = KEYS.alive("scene_memory_standby", "m-b")
    wait_for(lambda: standby in liveliness_tokens(client, KEYS.alive()), 60, "the standby")
    time.sleep(2.0)  # past the standby's start-up discovery
    before = stats(client)
    assert before is not None and (before.unknown, before.free, before.occupied) == expected
    active.send_signal(signal.SIGKILL)
    t0 = time.monotonic()
    wait_for(lambda: (s := stats(client)) is not None and s.seq == 1, 30, "the standby serving")
    took = time.monotonic() - t0
    print(f"a {size / 1e6:.0f} MB map served again {took:.2f} s after kill -9")
    assert took <= 2.0, took
    after = stats(client)
    assert (after.unknown, after.free, after.occupied) == expected
    np.testing.assert_array_equal(after.box_min, before.box_min)
