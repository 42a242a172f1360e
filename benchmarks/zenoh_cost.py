"""What one small message costs in Zenoh from Python on this machine, whatever AVS does with it:
a publisher process putting 200-byte messages at ``--rate`` Hz (express, as AVS's 1 kHz streams)
to a subscriber process, two peers on loopback, multicast off; the subscriber's handler only
counts (``--mode callback``), or is never called (``--mode none``: the samples stop in Zenoh's
own ring, no Python runs per message). Each process reports its CPU over ``--seconds``.

Last line: rate_hz=<x> publisher_cpu_percent=<x> subscriber_cpu_percent=<x>
subscriber_us_per_message=<x> (100 % = one core).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._loopback import free_endpoint  # noqa: E402


def _config(endpoint: str, listen: bool):
    import zenoh

    side = "listen" if listen else "connect"
    scouting = {"multicast": {"enabled": False}}
    return zenoh.Config.from_json5(
        json.dumps({"mode": "peer", side: {"endpoints": [endpoint]}, "scouting": scouting})
    )


def publisher(endpoint: str, rate: float, seconds: float, out: mp.Queue) -> None:
    import zenoh

    with zenoh.open(_config(endpoint, listen=True)) as session:
        pub = session.declare_publisher("bench/cost", express=True)
        payload, period = b"x" * 200, 1.0 / rate
        time.sleep(1.0)  # the subscriber connects
        t0, cpu0 = time.monotonic(), time.process_time()
        t = t0
        while time.monotonic() - t0 < seconds + 2.0:
            pub.put(payload)
            t += period
            time.sleep(max(0.0, t - time.monotonic()))
        out.put(("publisher", 100 * (time.process_time() - cpu0) / (time.monotonic() - t0), 0))


def subscriber(endpoint: str, mode: str, seconds: float, out: mp.Queue) -> None:
    import zenoh

    with zenoh.open(_config(endpoint, listen=False)) as session:
        count = [0]

        def on(_sample) -> None:
            count[0] += 1

        handler = on if mode == "callback" else zenoh.handlers.RingChannel(16)
        sub = session.declare_subscriber("bench/cost", handler)
        time.sleep(1.5)
        t0, cpu0, n0 = time.monotonic(), time.process_time(), count[0]
        time.sleep(seconds)
        took = time.monotonic() - t0
        out.put(("subscriber", 100 * (time.process_time() - cpu0) / took, (count[0] - n0) / took))
        sub.undeclare()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rate", type=float, default=1000.0)
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--mode", choices=["callback", "none"], default="callback")
    args = p.parse_args()
    if args.rate <= 0 or args.seconds <= 0:
        p.error("--rate and --seconds must be > 0")
    endpoint = free_endpoint()
    ctx = mp.get_context("spawn")
    out: mp.Queue = ctx.Queue()
    procs = [
        ctx.Process(target=publisher, args=(endpoint, args.rate, args.seconds, out)),
        ctx.Process(target=subscriber, args=(endpoint, args.mode, args.seconds, out)),
    ]
    procs[0].start()
    time.sleep(0.5)
    procs[1].start()
    results = {name: (cpu, rate) for name, cpu, rate in (out.get(timeout=60) for _ in procs)}
    for proc in procs:
        proc.join(10)
    pub_cpu, (sub_cpu, received) = results["publisher"][0], results["subscriber"]
    print(f"publisher {pub_cpu:.1f} % of a core; subscriber ({args.mode}) {sub_cpu:.1f} %, "
          f"{received:.0f} messages/s received")  # fmt: skip
    per = 1e6 * sub_cpu / 100 / args.rate
    print(
        f"rate_hz={args.rate:.0f} publisher_cpu_percent={pub_cpu:.1f} "
        f"subscriber_cpu_percent={sub_cpu:.1f} subscriber_us_per_message={per:.0f}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
