"""The thin publishing side of a bag replay: RgbdFrames onto ``sensors/rgbd/<camera>`` with
the key table's QoS (congestion BLOCK), paced by their stamps, with progress on stderr."""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Iterable
from typing import TextIO

from schemas import RgbdFrame
from services.common.node import Node

log = logging.getLogger("avs.adapters.rosbag")


class Progress:
    """One progress line on stderr: rewritten in place on a terminal, else every 10 %."""

    def __init__(self, total: int, out: TextIO = sys.stderr, label: str = "replay-bag") -> None:
        self.total, self.out, self.label = max(total, 1), out, label
        self.tty = out.isatty()
        self._last = -1

    def update(self, done: int, seconds: float) -> None:
        share = min(100, 100 * done // self.total)
        if self.tty:
            self.out.write(f"\r{self.label}: {done}/{self.total} frames ({share} %), "
                           f"{seconds:.1f} s recorded")  # fmt: skip
            self.out.flush()
        elif share // 10 > self._last // 10:
            self.out.write(f"{self.label}: {done}/{self.total} frames ({share} %)\n")
            self.out.flush()
        self._last = share

    def close(self) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()


def publish_frames(
    node: Node,
    frames: Iterable[RgbdFrame],
    camera: str,
    rate: float = 1.0,
    wait: float = 10.0,
    progress: Progress | None = None,
) -> int:
    """Put each frame on ``sensors/rgbd/<camera>`` at its stamp's offset from the first
    divided by ``rate`` (0: as fast as the link takes them); waits up to ``wait`` s for a
    subscriber first. Returns the frames published; stops early when the node stops."""
    out = node.publisher(node.keys.rgbd(camera))
    deadline = time.monotonic() + wait
    while not out.matched and time.monotonic() < deadline and not node.stopping:
        time.sleep(0.02)
    if not out.matched:
        log.warning("no subscriber on %s yet: publishing anyway", out.key)
    sent, first, start = 0, None, time.monotonic()
    for frame in frames:
        if first is None:
            first, start = frame.stamp, time.monotonic()
        if rate > 0:
            delay = start + (frame.stamp - first) / rate - time.monotonic()
            if delay > 0:
                node.spin(delay)
        if node.stopping:
            break
        out.put(frame)
        sent += 1
        if progress is not None:
            progress.update(sent, frame.stamp - first)
    return sent
