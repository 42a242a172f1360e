"""Nothing is lost on restart: every accepted update is journaled before it is applied, and
snapshots are written every so often; on start the latest snapshot is loaded and the journal
after it replayed.

Data directory layout:

- ``snapshot.pkl``: the whole memory (fusion, occupancy map, registered cloud) and the number
  of the last update it contains; written to a temporary file and renamed, so it is either
  the old one or the new one, never half of one;
- ``journal.log``: msgpack maps ``{"n": update number, "kind": "frame" | "observation",
  "payload": the message's bytes}``, one per update, flushed and fsynced. A record cut short by
  a crash (kill -9) is the update in flight: it is ignored.
"""

from __future__ import annotations

import logging
import os
import pickle
from pathlib import Path

import msgpack

log = logging.getLogger("avs.scene_memory")


class Store:
    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.snapshot_path = self.directory / "snapshot.pkl"
        self.journal_path = self.directory / "journal.log"
        self._journal = None

    def load(self) -> tuple[object | None, int, list[tuple[int, str, bytes]]]:
        """(the snapshot's state or None, its update number, the journal records after it).
        A record cut short at the journal's end (the update in flight at a crash) is cut off
        the file, so the records appended after a restart follow whole ones."""
        state, n = None, 0
        if self.snapshot_path.exists():
            with open(self.snapshot_path, "rb") as f:
                state, n = pickle.load(f)
        records: list[tuple[int, str, bytes]] = []
        if not self.journal_path.exists():
            return state, n, records
        good = 0
        with open(self.journal_path, "rb") as f:
            unpacker = msgpack.Unpacker(f, raw=False, max_buffer_size=1 << 30)
            try:
                for rec in unpacker:
                    if not (isinstance(rec, dict) and {"n", "kind", "payload"} <= rec.keys()):
                        break
                    good = unpacker.tell()
                    if rec["n"] > n:
                        records.append((int(rec["n"]), str(rec["kind"]), bytes(rec["payload"])))
            except (msgpack.OutOfData, ValueError):
                pass
        if good < self.journal_path.stat().st_size:
            log.warning(
                "journal: incomplete last record cut off",
                extra={"bytes": self.journal_path.stat().st_size - good},
            )
            with open(self.journal_path, "r+b") as f:
                f.truncate(good)
                os.fsync(f.fileno())
        return state, n, records

    def append(self, n: int, kind: str, payload: bytes) -> None:
        if self._journal is None:
            self._journal = open(self.journal_path, "ab")  # noqa: SIM115 - closed in close()
        self._journal.write(
            msgpack.packb({"n": n, "kind": kind, "payload": payload}, use_bin_type=True)
        )
        self._journal.flush()
        os.fsync(self._journal.fileno())

    def snapshot(self, state: object, n: int) -> None:
        """Write the state of update ``n`` atomically, then start an empty journal."""
        tmp = self.snapshot_path.with_suffix(".tmp")
        with open(tmp, "wb") as f:
            pickle.dump((state, n), f, protocol=pickle.HIGHEST_PROTOCOL)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.snapshot_path)
        if self._journal is not None:
            self._journal.close()
            self._journal = None
        # records up to n are in the snapshot; a crash before this truncation only leaves
        # records that load() skips by their number
        with open(self.journal_path, "wb") as f:
            os.fsync(f.fileno())

    def close(self) -> None:
        if self._journal is not None:
            self._journal.close()
            self._journal = None
