"""Two processes over a real Zenoh router on loopback: everything published arrives, equal."""

from __future__ import annotations

import threading

from schemas import ImuSample, Keys, RgbdFrame, decode
from tests.conftest import avs_env, wait_for
from tests.streams import imu_sample, rgbd_frame

N_IMU, N_FRAMES = 1000, 50


def test_imu_and_rgbd_streams_arrive_complete_and_equal(client, router, procs):
    keys = Keys()
    payloads: dict[str, list[bytes]] = {"imu": [], "rgbd": []}
    lock = threading.Lock()

    def keep(kind: str):
        def on_sample(sample) -> None:
            with lock:
                payloads[kind].append(sample.payload.to_bytes())

        return on_sample

    client.declare_subscriber(keys.imu(), keep("imu"))
    client.declare_subscriber(keys.rgbd("*"), keep("rgbd"))
    publisher = procs.python(
        ["tests/procs/publish_streams.py", str(N_IMU), str(N_FRAMES)], env=avs_env(router)
    )
    assert publisher.wait(60) == 0
    wait_for(
        lambda: len(payloads["imu"]) == N_IMU and len(payloads["rgbd"]) == N_FRAMES,
        10,
        f"{N_IMU} IMU samples and {N_FRAMES} frames",
        lambda: {k: len(v) for k, v in payloads.items()},
    )
    imus = [decode(p, ImuSample) for p in payloads["imu"]]
    assert [m.seq for m in imus] == list(range(N_IMU))  # in order, none lost
    assert all(m == imu_sample(m.seq) for m in imus)
    frames = [decode(p, RgbdFrame) for p in payloads["rgbd"]]
    assert [f.seq for f in frames] == list(range(N_FRAMES))
    for f in frames:
        assert f == rgbd_frame(f.seq)
        assert f.rgb.shape == (480, 640, 3) and f.depth.shape == (480, 640)
