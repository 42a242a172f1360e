"""The scene memory as a process over Zenoh: frames and observations in, the fused scene
published and served, occupancy stats and slices, the registered cloud; killed with SIGKILL in
the middle of a fusion run and restarted, it comes back with what it knew."""

from __future__ import annotations

import signal
import subprocess
import threading
import time

import numpy as np
import pytest
import zenoh

from schemas import (
    BoxQuery,
    Keys,
    OccupancySlice,
    OccupancyStats,
    PointCloud,
    SceneModel,
    SceneObservation,
    ServiceMetrics,
    decode,
    encode,
)
from services.scene_memory.persistence import Store
from tests.conftest import avs_env, liveliness_tokens, matched_publisher, wait_for
from tests.scene_memory.views import BOUNDS_MAX, BOUNDS_MIN, VOXEL, Update, reference, summary

KEYS = Keys()
PAGE = 200_000  # voxels per slice reply: the whole map comes in 10 pages


class Client:
    def __init__(self, session) -> None:
        self.session = session

    def get(self, key: str, schema, request=None, timeout: float = 10):
        payload = encode(request) if request is not None else None
        replies = [r.ok for r in self.session.get(key, payload=payload, timeout=timeout) if r.ok]
        assert len(replies) == 1, f"{len(replies)} replies on {key}"
        return decode(replies[0].payload.to_bytes(), schema)

    def scene(self) -> SceneModel:
        return self.get(KEYS.scene(), SceneModel)

    def stats(self) -> OccupancyStats:
        return self.get(KEYS.occupancy("stats"), OccupancyStats)

    def applied(self) -> int:
        return self.stats().seq


def sender(client, updates: list[Update]):
    """put(i) publishes update i (a frame or an observation) to the scene memory."""
    pub = {"frame": matched_publisher(client, KEYS.rgbd("head_rgbd"), timeout=60),
           "observation": matched_publisher(client, KEYS.observation(), timeout=30)}  # fmt: skip

    def put(i: int) -> None:
        kind, message = updates[i]
        pub[kind].put(encode(message))

    return put


def start(procs, router, data_dir, snapshot_every: int, instance: str = "m0"):
    args = [
        "-m", "services.scene_memory", "--instance", instance, "--data-dir", str(data_dir),
        "--voxel", str(VOXEL), "--snapshot-every", str(snapshot_every),
        "--slice-page-voxels", str(PAGE),
        f"--bounds-min={','.join(map(str, BOUNDS_MIN))}",
        f"--bounds-max={','.join(map(str, BOUNDS_MAX))}",
    ]  # fmt: skip
    return procs.python(args, env=avs_env(router))


def test_fuses_serves_and_survives_kill_9(client, router, procs, tmp_path, updates):
    published: list[SceneModel] = []
    lock = threading.Lock()

    def keep(sample):
        with lock:
            published.append(decode(sample.payload.to_bytes(), SceneModel))

    client.declare_subscriber(KEYS.scene(), keep)
    c = Client(client)
    service = start(procs, router, tmp_path, snapshot_every=4)
    put = sender(client, updates)

    def send(i: int) -> None:
        put(i)

    # the first seven updates, each one applied before the next is sent
    for i in range(7):
        send(i)
        wait_for(lambda i=i: c.applied() == i + 1, 60, f"update {i + 1}")
    before_scene, before_stats = c.scene(), c.stats()
    expected = reference(updates[:7])
    assert summary(before_scene) == summary(expected.scene(7, 7.0))
    assert (before_stats.unknown, before_stats.free, before_stats.occupied) == (
        expected.occupancy.counts()
    )
    assert before_stats.occupied > 1000 and before_stats.frames_integrated == 4
    # every observation published the scene
    wait_for(lambda: len(published) == 3, 10, "three published scenes")
    assert summary(published[-1]) == summary(before_scene)
    # each names the frame whose observation it fused (what benchmarks/pipeline.py times)
    observed = [m for _, m in updates[:7] if isinstance(m, SceneObservation)]
    assert [m.frame_seq for m in published] == [o.frame_seq for o in observed]
    # a slice of the map and the registered cloud
    box = BoxQuery(box_min=np.array([0.5, -0.5, 0.5]), box_max=np.array([1.5, 0.5, 1.2]))
    piece = c.get(KEYS.occupancy("slice"), OccupancySlice, box)
    assert piece.states.shape == (50, 50, 36)  # the voxels the box touches: z from -0.05
    counts = c.get(KEYS.occupancy("stats"), OccupancyStats, box)
    assert np.bincount(piece.states.ravel(), minlength=3).tolist() == [
        counts.unknown, counts.free, counts.occupied
    ]  # fmt: skip
    # the whole map, paged: slabs along x that join into the map, none over the page size
    pages = [decode(r.ok.payload.to_bytes(), OccupancySlice)
             for r in client.get(KEYS.occupancy("slice"), timeout=10,
                                 consolidation=zenoh.ConsolidationMode.NONE) if r.ok]  # fmt: skip
    assert len(pages) == pages[0].pages == 10 and all(p.states.size <= PAGE for p in pages)
    whole = OccupancySlice.join(pages)
    assert whole.states.shape == expected.occupancy.shape
    assert np.bincount(whole.states.ravel(), minlength=3).tolist() == [
        before_stats.unknown, before_stats.free, before_stats.occupied
    ]  # fmt: skip
    with pytest.raises(ValueError, match="no complete"):
        OccupancySlice.join(pages[:-1])
    cloud = c.get(KEYS.cloud(), PointCloud)
    assert 5000 < len(cloud.points) <= 100_000

    # the eighth update in flight: kill -9 right after sending it
    send(7)
    time.sleep(0.005)
    service.send_signal(signal.SIGKILL)
    service.wait(10)
    assert service.returncode == -signal.SIGKILL
    assert (tmp_path / "snapshot.avs").is_file() and (tmp_path / "journal.log").is_file()

    service = start(procs, router, tmp_path, snapshot_every=4)
    wait_for(lambda: _answers(c), 60, "the restarted service")
    restored = c.applied()
    assert restored in (7, 8), restored  # the update in flight may or may not have landed
    after_scene, after_stats = c.scene(), c.stats()
    if restored == 7:
        assert summary(after_scene) == summary(before_scene)
        after, before = (s.model_dump(exclude={"stamp"}) for s in (after_stats, before_stats))
        assert after.keys() == before.keys()
        for name, value in before.items():  # the box corners are arrays: compare element-wise
            assert np.array_equal(after[name], value), (name, after[name], value)
        send(7)  # the sender retries what was lost
    # and the run goes on to the end, ending where an uninterrupted run ends
    for i in range(8, len(updates)):
        wait_for(lambda i=i: c.applied() >= i, 60, f"update {i}")
        send(i)
    wait_for(lambda: c.applied() == len(updates), 60, "the last update")
    final = reference(updates)
    assert summary(c.scene()) == summary(final.scene())
    s = c.stats()
    assert (s.unknown, s.free, s.occupied) == final.occupancy.counts()
    metrics = c.get(KEYS.metrics("scene_memory", "m0"), ServiceMetrics)
    assert metrics.dropped == {}


@pytest.mark.timeout(300)
def test_a_standby_takes_over_within_2_s_when_the_active_is_killed(
    client, router, procs, tmp_path, updates
):
    """Two instances on one data directory: one active, one standing by (no inputs, no
    queryables, its own token). kill -9 the active: the standby restores what was journaled
    and serves memory/scene within 1.5 s (the issue asks for 2), nothing lost, and the run goes
    on to the end."""
    c = Client(client)
    active = start(procs, router, tmp_path, 4, "m-a")
    wait_for(lambda: KEYS.alive("scene_memory", "m-a") in liveliness_tokens(client, KEYS.alive()),
             60, "the active instance")  # fmt: skip
    start(procs, router, tmp_path, 4, "m-b")
    standby = KEYS.alive("scene_memory_standby", "m-b")
    wait_for(lambda: standby in liveliness_tokens(client, KEYS.alive()), 60, "the standby")
    # a standby that has been standing by: past its start-up discovery (1.5 s), in which it
    # only looks for other instances (a kill within it took 1.45 s to serve, not 0.4 s)
    time.sleep(2.0)
    put = sender(client, updates)

    def send(i: int) -> None:
        put(i)
        wait_for(lambda: c.applied() == i + 1, 60, f"update {i + 1}")

    for i in range(6):
        send(i)
    before = summary(c.scene())
    active.send_signal(signal.SIGKILL)
    t0 = time.monotonic()
    wait_for(lambda: _answers(c) and c.applied() == 6, 10, "the standby to serve")
    took = time.monotonic() - t0
    print(f"the standby served memory/scene {took:.2f} s after the kill")
    assert took <= 1.5, took
    assert summary(c.scene()) == before  # nothing lost
    assert KEYS.alive("scene_memory", "m-b") in liveliness_tokens(client, KEYS.alive())
    for i in range(6, len(updates)):
        send(i)
    assert summary(c.scene()) == summary(reference(updates).scene())


def test_a_standby_stops_on_a_signal_and_does_not_take_over(client, router, procs, tmp_path):
    """SIGTERM to an instance standing by ends it within 2 s, without taking over, while the
    active one goes on. It used to stand by through its signal (a node acts on one once it
    spins): at a Ctrl-C of ``avs up``, when the active one went, it took over and restored
    the whole map only to stop."""
    active = start(procs, router, tmp_path, 4, "m-a")
    wait_for(lambda: KEYS.alive("scene_memory", "m-a") in liveliness_tokens(client, KEYS.alive()),
             60, "the active instance")  # fmt: skip
    standby = procs.python(
        ["-m", "services.scene_memory", "--instance", "m-b", "--data-dir", str(tmp_path)],
        env=avs_env(router), stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    token = KEYS.alive("scene_memory_standby", "m-b")
    wait_for(lambda: token in liveliness_tokens(client, KEYS.alive()), 60, "the standby")
    time.sleep(2.0)  # past its start-up discovery
    standby.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    assert standby.wait(10) == 0
    took = time.monotonic() - t0
    assert took < 2.0, took
    assert "taking over" not in standby.stderr.read()
    assert KEYS.alive("scene_memory", "m-a") in liveliness_tokens(client, KEYS.alive())
    assert Client(client).applied() == 0  # the active one still answers
    active.send_signal(signal.SIGTERM)
    assert active.wait(30) == 0


def _answers(c: Client) -> bool:
    try:
        c.applied()
        return True
    except AssertionError:
        return False


def test_a_record_cut_short_is_dropped_and_the_journal_goes_on(tmp_path):
    store = Store(tmp_path)
    store.append(1, "observation", b"one")
    store.append(2, "observation", b"two")
    store.close()
    with open(tmp_path / "journal.log", "ab") as f:
        f.write(b"\x83\xa1n\x03\xa4kind")  # the start of a third record: a crash mid-write
    again = Store(tmp_path)
    _, n, records = again.load()
    assert n == 0 and [r[0] for r in records] == [1, 2]
    again.append(3, "frame", b"three")
    again.close()
    _, _, records = Store(tmp_path).load()
    assert [(r[0], r[2]) for r in records] == [(1, b"one"), (2, b"two"), (3, b"three")]


def test_a_snapshot_replaces_the_journal_and_records_before_it_are_skipped(tmp_path):
    store = Store(tmp_path)
    for n in (1, 2, 3):
        store.append(n, "observation", bytes([n]))
    store.snapshot({"state": 3}, 3)
    store.append(4, "observation", b"\x04")
    store.close()
    state, n, records = Store(tmp_path).load()
    assert state == {"state": 3} and n == 3 and [r[0] for r in records] == [4]
