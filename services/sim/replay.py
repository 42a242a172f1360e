"""Replay: the second implementation of the sensor contract. It puts the payloads of an MCAP
recording (``avs record``) back on their keys in log-time order with their recorded timing
(scaled by --speed), so a consumer cannot tell it from the sim. It answers sim/control with its
status and stops the node at the end."""

from __future__ import annotations

import itertools
import logging
import time
from pathlib import Path

from schemas import SimControl, SimStatus
from services.common.node import Node, Output
from services.common.playback import Recording, open_recording
from services.common.recording import RecordingError
from services.common.transport import LOSSLESS
from services.sim.config import SimSettings

log = logging.getLogger("avs.sim")


def open_replay(path: Path) -> Recording:
    """The recording to play; a ``ValueError`` names the file and what is wrong with it."""
    return open_recording(path)


class ReplayNode:
    def __init__(self, node: Node, settings: SimSettings, recording: Recording) -> None:
        self.node, self.settings = node, settings
        self.recording, self.records = recording, recording.records
        self.outputs: dict[str, Output] = {}
        self.played = 0
        self.t = 0.0
        for key in recording.counts:  # declared up front: a declaration costs time mid-replay
            self._output(key)
        node.serve(node.keys.sim_control(), self.on_control, SimControl)
        node.start_thread(self.play, "sim:replay")
        log.info(
            "replaying",
            extra={
                "file": str(settings.replay),
                "keys": recording.keys,
                "counts": recording.counts,
            },
        )

    def _output(self, key: str) -> Output:
        """A recorded key's publisher. Every message of a recording is put, none dropped on
        congestion: a slow subscriber holds the replay back (at --speed 5 the 1 kHz IMU comes
        at 5 kHz, and 29 of 300 samples were dropped on the key table's QoS in CI)."""
        if key not in self.outputs:
            self.outputs[key] = self.node.publisher(key, **LOSSLESS)
        return self.outputs[key]

    def play(self) -> None:
        try:
            self._play()
        except RecordingError as e:
            log.error("replay stopped: %s", e)
        log.info("replay finished", extra={"records": self.played})
        # linger before closing the session, as a socket does: the last large frames may still
        # be on their way through the router
        self.node.wait(self.settings.replay_linger)
        self.node.stop()

    def _play(self) -> None:
        first = next(self.records, None)
        if first is not None:  # give subscribers a moment to match the first key
            out = self._output(first.key)
            deadline = time.monotonic() + self.settings.replay_wait
            while not out.matched and time.monotonic() < deadline and not self.node.stopping:
                time.sleep(0.01)
        start = time.monotonic() - (first.t if first else 0.0) / self.settings.speed
        for record in itertools.chain([first] if first else [], self.records):
            if self.node.stopping:
                return
            delay = start + record.t / self.settings.speed - time.monotonic()
            if delay > 0 and self.node.wait(delay):
                return
            self._output(record.key).put_raw(record.payload)
            self.played += 1
            self.t = record.t

    def on_control(self, request: SimControl | None) -> SimStatus:
        ok = request is None or request.op == "status"
        return SimStatus(
            ok=ok,
            error="" if ok else "a replay only answers status",
            mode="replay",
            scene=str(self.settings.replay),
            robot=self.settings.robot,
            sim_time=self.t,
            steps=self.played,
        )
