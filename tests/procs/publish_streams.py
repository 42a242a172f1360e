"""Child process of the transport test: publish N ImuSamples at 1 kHz and M RgbdFrames at 30 Hz
as a client of the router given by AVS_CONNECT, once a subscriber matches each key."""

from __future__ import annotations

import sys
import threading
import time

from schemas import Keys
from services.common import Node, ServiceSettings
from tests.conftest import wait_for
from tests.streams import imu_sample, rgbd_frame


def pace(period: float, n: int, send) -> None:
    t0 = time.perf_counter()
    for i in range(n):
        send(i)
        delay = t0 + (i + 1) * period - time.perf_counter()
        if delay > 0:
            time.sleep(delay)


def main() -> None:
    n_imu, n_frames = int(sys.argv[1]), int(sys.argv[2])
    keys = Keys()
    with Node("publisher", ServiceSettings.from_args([])) as node:
        imu, rgbd = node.publisher(keys.imu()), node.publisher(keys.rgbd("head_rgbd"))
        wait_for(lambda: imu.matched and rgbd.matched, 30, "subscribers")
        frames = [rgbd_frame(i) for i in range(n_frames)]
        t = threading.Thread(target=pace, args=(1 / 30, n_frames, lambda i: rgbd.put(frames[i])))
        t.start()
        pace(1e-3, n_imu, lambda i: imu.put(imu_sample(i)))
        t.join()


if __name__ == "__main__":
    main()
