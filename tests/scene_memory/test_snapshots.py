"""Snapshots are data, checked before use: a real memory survives the round trip exactly, a
truncated or bit-flipped snapshot is refused with one log line and the previous snapshot plus
the journals restore the state, and a snapshot naming any other class is refused."""

from __future__ import annotations

import hashlib
import io
import logging

import msgpack
import numpy as np
import pytest

from schemas import encode
from services.scene_memory import state as state_file
from services.scene_memory.node import SceneMemoryNode
from services.scene_memory.persistence import Store
from tests.scene_memory.views import reference, summary


@pytest.fixture(scope="module")
def memories(updates):
    """The memory after 4 updates and after all 12 (tabletop_clutter, six views)."""
    return reference(updates[:4]), reference(updates)


def test_a_memory_survives_the_round_trip_exactly(memories):
    _, full = memories
    data = state_file.dump(full, 12)
    restored, n = state_file.load(data)
    assert n == 12
    assert summary(restored.scene(12, 12.0)) == summary(full.scene(12, 12.0))
    # the model still names the frame it fused last (what benchmarks/pipeline.py times)
    assert restored.scene().frame_seq == full.scene().frame_seq is not None
    assert np.array_equal(restored.occupancy.L, full.occupancy.L)
    assert restored.occupancy.counts() == full.occupancy.counts()
    assert np.array_equal(restored.cloud, full.cloud)
    assert restored.fusion.occ == full.fusion.occ and restored.fusion.occ  # (id, id) keys
    assert len(data) < full.occupancy.L.nbytes, len(data)  # known voxels only, not the grid


@pytest.mark.parametrize("damage", ["truncated", "bit_flipped"])
def test_a_damaged_snapshot_is_refused_and_the_previous_one_restores(
    tmp_path, updates, memories, damage, caplog
):
    _, full = memories
    store = Store(tmp_path)
    for n, (kind, message) in enumerate(updates, start=1):
        store.append(n, kind, encode(message))
        if n in (4, 8):
            store.snapshot(reference(updates[:n]), n)
    store.close()
    data = (tmp_path / "snapshot.avs").read_bytes()
    if damage == "truncated":
        data = data[: len(data) // 2]
    else:
        flipped = bytearray(data)
        flipped[len(data) // 2] ^= 0x10
        data = bytes(flipped)
    (tmp_path / "snapshot.avs").write_bytes(data)
    with caplog.at_level(logging.ERROR, logger="avs.scene_memory"):
        state, n, records = Store(tmp_path).load()
    refused = [r for r in caplog.records if "snapshot refused" in r.getMessage()]
    assert len(refused) == 1 and "checksum" in refused[0].getMessage()
    assert n == 4 and [r[0] for r in records] == list(range(5, 13))
    for _, kind, payload in records:
        SceneMemoryNode._apply(state, kind, payload)
    assert summary(state.scene(12, 12.0)) == summary(full.scene(12, 12.0))
    assert state.occupancy.counts() == full.occupancy.counts()


def test_a_snapshot_naming_another_class_is_refused():
    """A checksum-valid file that asks for os.system (or any class off the list) is refused:
    loading never imports or calls what a file names."""
    tree = {"__object__": "system", "state": {"command": "touch /tmp/owned"}}
    body = msgpack.packb(
        {"version": state_file.VERSION, "n": 1, "tree": tree, "arrays": _empty_npz()},
        use_bin_type=True,
    )
    data = state_file.MAGIC + hashlib.sha256(body).digest() + body
    with pytest.raises(state_file.StateError, match="not allowed"):
        state_file.load(data)
    with pytest.raises(state_file.StateError, match="version"):
        state_file.load(_with_version(2))


def _empty_npz() -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer)
    return buffer.getvalue()


def _with_version(version: int) -> bytes:
    body = msgpack.packb(
        {"version": version, "n": 1, "tree": None, "arrays": _empty_npz()}, use_bin_type=True
    )
    return state_file.MAGIC + hashlib.sha256(body).digest() + body


def test_snapshots_take_at_most_their_share_of_the_time():
    """Updates of 0.1 s each and a 0.35 s snapshot (a kitchen map's): with the default share
    (10 %) a snapshot comes once the journal holds 3.15 s of updates, not every 0.5 s; cheap
    snapshots keep the old bounds (every 20 updates or 0.5 s of journal)."""
    from services.scene_memory.persistence import snapshot_due

    def snapshots(apply_s: float, snapshot_s: float, updates: int = 400) -> list[int]:
        written, replay, last = [], 0.0, 0.0
        for n in range(1, updates + 1):
            replay += apply_s
            if snapshot_due(n, replay, last, every=20, max_replay_s=0.5, share=0.1):
                written.append(n)
                replay, last = 0.0, snapshot_s
        return written

    slow = snapshots(0.1, 0.35)
    assert slow[0] == 5 and np.all(np.diff(slow) == 32), slow  # 32 × 0.1 s ≥ 9 × 0.35 s
    cheap = snapshots(0.01, 0.002)
    assert cheap[:3] == [20, 40, 60]  # every 20 updates: 0.2 s of journal, 0.002 s to write
    assert snapshots(0.2, 0.01)[:3] == [3, 6, 9]  # every 0.5 s of journal


@pytest.mark.parametrize("crash", ["while_writing", "after"])
def test_a_snapshot_written_while_updates_go_on_restores_everything(
    tmp_path, updates, memories, crash
):
    """``begin_snapshot`` captures the state of update 8 and rotates the journal; updates 9-12
    are journaled (and applied to the live memory) before the file is made. A crash before it
    is in place restores from the snapshot of update 4 and both journals; after, from update
    8's snapshot: the state of all 12 updates either way, and the capture is update 8's state
    (not what the memory became while it was written)."""
    _, full = memories
    store = Store(tmp_path)
    live = reference([])
    for n, (kind, message) in enumerate(updates, start=1):
        store.append(n, kind, encode(message))
        SceneMemoryNode._apply(live, kind, encode(message))
        if n == 4:
            store.snapshot(reference(updates[:n]), n)
        if n == 8:
            finish = store.begin_snapshot(live, n)
    store.close()
    if crash == "after":
        finish()
    state, n, records = Store(tmp_path).load()
    assert n == (8 if crash == "after" else 4)
    assert [r[0] for r in records] == list(range(n + 1, 13))
    if crash == "after":
        eight = reference(updates[:8])
        assert summary(state.scene(8, 8.0)) == summary(eight.scene(8, 8.0))
        assert np.array_equal(state.occupancy.L, eight.occupancy.L)
        # the cloud, kept without a copy (replaced by each frame, never written in place)
        assert np.array_equal(state.cloud, eight.cloud) and len(eight.cloud) < len(live.cloud)
    for _, kind, payload in records:
        SceneMemoryNode._apply(state, kind, payload)
    assert summary(state.scene(12, 12.0)) == summary(full.scene(12, 12.0))
    assert state.occupancy.counts() == full.occupancy.counts()


def test_an_observation_replays_with_the_correction_it_was_fused_with(updates):
    """The node fuses observations on one thread while frames are registered on another, so
    the odometry correction an observation was fused with is journaled with it: replayed
    after the map's correction moved on (or before it existed), it is fused as it was live.
    Without the record's correction (the old kind) the replay would use the memory's own and
    the primitives land 5 cm away."""
    from scipy.spatial.transform import Rotation

    from services.scene_memory.node import OBSERVATION_CORRECTED, pack_observation

    k, obs = [(i, m) for i, (kind, m) in enumerate(updates) if kind == "observation"][1]
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 2, degrees=True).as_matrix()
    T[:3, 3] = [0.05, -0.02, 0.0]
    other = np.eye(4)
    other[:3, 3] = [-0.03, 0.04, 0.01]

    live = reference(updates[:k])
    live.fuse(obs, T)
    payload = pack_observation(encode(obs), T)
    for before in (None, other):  # what the map's side holds when the record is replayed
        replayed = reference(updates[:k])
        replayed.T_world_odom = before
        SceneMemoryNode._apply(replayed, OBSERVATION_CORRECTED, payload)
        assert summary(replayed.scene()) == summary(live.scene())
    old_kind = reference(updates[:k])
    old_kind.T_world_odom = other
    SceneMemoryNode._apply(old_kind, "observation", encode(obs))
    assert summary(old_kind.scene()) != summary(live.scene())
    # no correction when it was fused: none when replayed, whatever the memory holds now
    unmoved = reference(updates[:k])
    unmoved.T_world_odom = other
    SceneMemoryNode._apply(unmoved, OBSERVATION_CORRECTED, pack_observation(encode(obs), None))
    plain = reference(updates[:k])
    plain.fuse(obs, None)
    assert summary(unmoved.scene()) == summary(plain.scene())


def test_a_capture_copies_every_array_but_those_replaced_or_made_for_it(memories):
    """The cloud (replaced by each frame, never written in place) and the map's packed known
    voxels (made for the snapshot) are kept as they are; every other array is a copy."""
    _, full = memories
    _, arrays = state_file.capture(full)
    kept = [a for a in arrays if a is full.cloud or a is full.colours or a is full.viewpoints]
    assert len(kept) == 3
    live = [v for v in vars(full.fusion).values() if isinstance(v, np.ndarray)]
    live += [full.occupancy.L, *(v for v in vars(full).values() if isinstance(v, np.ndarray))]
    shared = [a for a in arrays if any(np.shares_memory(a, b) for b in live)]
    assert len(shared) == 3, [a.shape for a in shared]
