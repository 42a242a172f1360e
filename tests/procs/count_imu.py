"""Child process of the lockstep stall test: a client of the router at argv[1] with 64 KB socket
buffers (so a backlog cannot hide in them) that subscribes to the IMU, prints "subscribed", and
once it holds argv[2] samples, or none came for 10 s, prints the sequence numbers it received
as one JSON line, with the payloads it could not decode. The test stops this process
(SIGSTOP) while the sim steps: a real stall, with no Zenoh thread blocked in a callback."""

from __future__ import annotations

import json
import sys
import threading
import time

import zenoh

from schemas import ImuSample, Keys, decode
from tests.conftest import session_config


def main() -> None:
    endpoint, n = sys.argv[1], int(sys.argv[2])
    config = session_config("client", connect=[endpoint])
    config.insert_json5("transport/link/tcp", json.dumps({"so_sndbuf": 65536, "so_rcvbuf": 65536}))
    seqs: list[int] = []
    errors: list[str] = []
    last = [time.monotonic()]
    done = threading.Event()

    def on_sample(sample: zenoh.Sample) -> None:
        try:
            seqs.append(decode(sample.payload.to_bytes(), ImuSample).seq)
        except Exception as e:  # reported to the test
            errors.append(repr(e))
        last[0] = time.monotonic()
        if len(seqs) >= n:
            done.set()

    with zenoh.open(config) as session:
        session.declare_subscriber(Keys().imu(), on_sample)
        time.sleep(0.5)  # the subscription reaches the router
        print("subscribed", flush=True)
        while not done.wait(0.1):
            if time.monotonic() - last[0] > 10:
                break
        print(json.dumps({"seqs": seqs, "errors": errors}), flush=True)


if __name__ == "__main__":
    main()
