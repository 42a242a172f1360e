"""Nothing is lost on restart: every accepted update is journaled before it is applied, and
snapshots are written every so often; on start the latest good snapshot is loaded and the
journal after it replayed.

Data directory layout:

- ``snapshot.avs``: the whole memory (fusion, occupancy map, registered cloud) and the number
  of the last update it contains, as data (``state.py``: msgpack + npz, versioned, sha-256);
  written to a temporary file and renamed, so it is either the old one or the new one;
- ``snapshot.prev.avs``: the one before it, used when the latest is refused (truncated,
  bit-flipped, of another version);
- ``journal.log``: msgpack maps ``{"n": update number, "kind": "frame" | "skip" |
  "observation+correction" (| "observation", from before corrections were journaled),
  "payload": the message's bytes}`` (an observation's: msgpack ``{"observation": its bytes,
  "T_world_odom": the 16 numbers of the odometry correction it was fused with, or nil}``), one
  per update after the latest snapshot, flushed and fsynced. A record cut short by a crash
  (kill -9) is the update in flight: it is ignored;
- ``journal.prev.log``: the records between the previous snapshot and the latest.

Restoring replays, from both journals, the records after the snapshot used, in order, and
stops at a gap (a state is never built on a missing update).
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from pathlib import Path

import msgpack

from services.scene_memory import state as state_file

log = logging.getLogger("avs.scene_memory")

Record = tuple[int, str, bytes]


def snapshot_due(
    n: int, replay_s: float, snapshot_s: float, every: int, max_replay_s: float, share: float
) -> bool:
    """Whether to write a snapshot after update ``n``: what a restart would replay is bounded
    (a snapshot every ``every`` updates, or sooner once applying the journal since the last one
    took ``max_replay_s``), but snapshots take at most ``share`` of the time: the journal's
    ``replay_s`` must have grown to ``snapshot_s`` (the last one's cost) × (1/share − 1). A
    kitchen map's snapshot takes 0.2-0.4 s; one every 0.5 s of updates would cost as much as
    the updates themselves."""
    due = n % every == 0 or replay_s >= max_replay_s
    return due and replay_s * share >= snapshot_s * (1 - share)


class Store:
    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.snapshot_path = self.directory / "snapshot.avs"
        self.previous_path = self.directory / "snapshot.prev.avs"
        self.journal_path = self.directory / "journal.log"
        self.previous_journal = self.directory / "journal.prev.log"
        self._journal = None
        if (self.directory / "snapshot.pkl").exists():
            log.warning(
                "snapshot.pkl ignored: pickle snapshots are no longer loaded (they can run code);"
                " the state restarts from snapshot.avs and the journal",
                extra={"path": str(self.directory / "snapshot.pkl")},
            )

    def _snapshot(self) -> tuple[object | None, int]:
        """The latest snapshot that passes its checks, else the previous one, else none."""
        for path in (self.snapshot_path, self.previous_path):
            if not path.exists():
                continue
            try:
                return state_file.load(path.read_bytes())
            except state_file.StateError as e:
                log.error("snapshot refused: %s", e, extra={"path": str(path)})
        return None, 0

    def load(self) -> tuple[object | None, int, list[Record]]:
        """(the snapshot's state or None, its update number, the journal records after it).
        A record cut short at the journal's end (the update in flight at a crash) is cut off
        the file, so the records appended after a restart follow whole ones."""
        state, n = self._snapshot()
        records: dict[int, Record] = {}
        for path in (self.previous_journal, self.journal_path):
            for record in self._read(path, truncate=path == self.journal_path):
                if record[0] > n:
                    records[record[0]] = record
        replay: list[Record] = []
        for number in sorted(records):
            if number != n + len(replay) + 1:
                log.error("journal: update %d missing; replay stops before it", n + len(replay) + 1)
                break
            replay.append(records[number])
        return state, n, replay

    def _read(self, path: Path, truncate: bool) -> list[Record]:
        records: list[Record] = []
        if not path.exists():
            return records
        good = 0
        with open(path, "rb") as f:
            unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 30)
            try:
                for rec in unpacker:
                    if not (isinstance(rec, dict) and {"n", "kind", "payload"} <= rec.keys()):
                        break
                    good = unpacker.tell()
                    records.append((int(rec["n"]), str(rec["kind"]), bytes(rec["payload"])))
            except (msgpack.OutOfData, ValueError):
                pass
        size = path.stat().st_size
        if truncate and good < size:
            log.warning("journal: incomplete last record cut off", extra={"bytes": size - good})
            with open(path, "r+b") as f:
                f.truncate(good)
                os.fsync(f.fileno())
        return records

    def append(self, n: int, kind: str, payload: bytes) -> None:
        if self._journal is None:
            self._journal = open(self.journal_path, "ab")  # noqa: SIM115 - closed in close()
        self._journal.write(
            msgpack.packb({"n": n, "kind": kind, "payload": payload}, use_bin_type=True)
        )
        self._journal.flush()
        os.fsync(self._journal.fileno())

    def snapshot(self, state: object, n: int) -> None:
        """Write the state of update ``n``; the latest snapshot and its journal become the
        previous ones. At every step a crash leaves a restorable directory: either snapshot
        with the records after it in the two journals."""
        tmp = self._written(state_file.dump(state, n))
        self.close()
        if self.snapshot_path.exists():
            os.replace(self.snapshot_path, self.previous_path)
        if self.journal_path.exists():
            os.replace(self.journal_path, self.previous_journal)
        os.replace(tmp, self.snapshot_path)
        self._sync_directory()

    def begin_snapshot(self, state: object, n: int) -> Callable[[], None]:
        """``snapshot`` in two parts: now (the state must stand still) the state is captured
        and the journal rotated (records after ``n`` go to a new one); the returned call makes
        the file and puts it in place, while updates go on (a thread of its own). Until it has,
        the latest snapshot with both journals restores everything (the previous snapshot has
        lost its journal: a crash in that window must not also meet a damaged latest one)."""
        tree, arrays = state_file.capture(state)
        self.close()
        if self.journal_path.exists():
            os.replace(self.journal_path, self.previous_journal)
        self._sync_directory()

        def finish() -> None:
            tmp = self._written(state_file.serialise(tree, arrays, n))
            if self.snapshot_path.exists():
                os.replace(self.snapshot_path, self.previous_path)
            os.replace(tmp, self.snapshot_path)
            self._sync_directory()

        return finish

    def _written(self, data: bytes) -> Path:
        """``data`` in the temporary snapshot file, flushed and fsynced; its path."""
        tmp = self.snapshot_path.with_suffix(".tmp")
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        return tmp

    def _sync_directory(self) -> None:
        fd = os.open(self.directory, os.O_RDONLY)
        try:
            os.fsync(fd)  # the renames themselves
        finally:
            os.close(fd)

    def close(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None
