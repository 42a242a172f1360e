"""The node shell over a real Zenoh session on loopback: validation, drops, metrics, liveliness,
queries, latest-only inputs."""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest

from schemas import (
    ImuSample,
    JointState,
    Keys,
    ServiceMetrics,
    SimControl,
    SimStatus,
    decode,
    encode,
)
from services.common import Node, RemoteError, ServiceSettings
from services.common.realtime import BACKGROUND
from tests.conftest import liveliness_tokens, matched_publisher, wait_for


def imu(seq: int) -> ImuSample:
    return ImuSample(
        seq=seq,
        stamp=seq * 1e-3,
        angular_velocity=np.array([0.0, 0.0, seq]),
        linear_acceleration=np.array([0.0, 0.0, 9.81]),
        orientation=np.array([1.0, 0.0, 0.0, 0.0]),
    )


@pytest.fixture
def node(router):
    settings = ServiceSettings(mode="client", connect=[router], multicast=False, instance="t0")
    with Node("tester", settings) as n:
        yield n


def test_invalid_inputs_are_dropped_counted_and_logged_once(node, client, caplog):
    keys = Keys()
    got: list[ImuSample] = []
    node.subscribe(keys.imu(), ImuSample, got.append)
    bad = [
        b"\x00\x01garbage",  # malformed
        msgpack.packb({"schema": "Nope", "version": 1}),  # unknown_schema
        msgpack.packb({"schema": "ImuSample", "version": 9}),  # wrong_version
        encode(JointState(names=["a"], position=np.zeros(1), velocity=np.zeros(1))),
        b"\x00\x02garbage",  # malformed again: counted, not logged again
    ]
    publisher = matched_publisher(client, keys.imu())
    with caplog.at_level(logging.WARNING, logger="avs.tester"):
        for payload in bad:
            publisher.put(payload)
        for i in range(5):
            publisher.put(encode(imu(i)))
        wait_for(
            lambda: len(got) == 5 and node.metrics.dropped_total == 5,
            10,
            "all samples",
            lambda: (len(got), node.metrics.snapshot()),
        )
    assert [m.seq for m in got] == [0, 1, 2, 3, 4]
    dropped = node.metrics.snapshot().dropped
    assert dropped == {
        "malformed": 2,
        "unknown_schema": 1,
        "wrong_version": 1,
        "unexpected_schema": 1,
    }
    warnings = [r for r in caplog.records if "dropping message" in r.getMessage()]
    assert len(warnings) == 4  # once per reason
    assert node.metrics.snapshot().messages_in == {keys.imu(): 10}
    assert node.metrics.snapshot().messages_valid == {keys.imu(): 5}  # the good ones only


def test_a_raising_handler_is_counted_and_the_node_goes_on(node, client):
    keys = Keys()
    seen: list[int] = []

    def handler(m: ImuSample) -> None:
        seen.append(m.seq)
        if m.seq == 1:
            raise RuntimeError("boom")

    node.subscribe(keys.imu(), ImuSample, handler)
    publisher = matched_publisher(client, keys.imu())
    for i in range(3):
        publisher.put(encode(imu(i)))
    wait_for(lambda: len(seen) == 3, 10, "three messages")
    assert node.metrics.snapshot().dropped == {"handler_error:RuntimeError": 1}


def test_metrics_queryable_and_liveliness(node, client):
    keys = Keys()
    # the token travels node -> router -> client like any declaration: wait for it, then the set
    wait_for(lambda: liveliness_tokens(client, keys.alive()), 10, "the node's token")
    assert liveliness_tokens(client, keys.alive()) == {keys.alive("tester", "t0")}
    node.subscribe(keys.imu(), ImuSample, lambda m: None)
    matched_publisher(client, keys.imu()).put(b"junk")
    wait_for(lambda: node.metrics.dropped_total == 1, 10, "the drop")
    replies = [r.ok for r in client.get(keys.metrics(), timeout=5) if r.ok]
    assert len(replies) == 1
    metrics = decode(replies[0].payload.to_bytes(), ServiceMetrics)
    assert (metrics.service, metrics.instance) == ("tester", "t0")
    assert metrics.dropped == {"malformed": 1}
    assert metrics.uptime_s > 0


def test_liveliness_token_goes_with_the_node(router, client):
    settings = ServiceSettings(mode="client", connect=[router], multicast=False, instance="t1")
    node = Node("shortlived", settings)
    key = Keys().alive("shortlived", "t1")
    wait_for(lambda: key in liveliness_tokens(client, Keys().alive()), 10, "the token")
    node.close()
    wait_for(lambda: key not in liveliness_tokens(client, Keys().alive()), 10, "the token to go")


def test_serve_and_query(node, router):
    keys = Keys()

    def control(request: SimControl) -> SimStatus:
        if request.op == "pause":
            raise ValueError("cannot pause")
        return SimStatus(
            ok=True, mode="lockstep", scene="s", robot="r", sim_time=0, steps=request.n
        )

    node.serve(keys.sim_control(), control, SimControl)
    settings = ServiceSettings(mode="client", connect=[router], multicast=False, instance="q")
    with Node("asker", settings) as asker:
        (status,) = asker.query(keys.sim_control(), SimControl(op="step", n=4), SimStatus)
        assert status.steps == 4
        with pytest.raises(RemoteError, match="ValueError: cannot pause"):
            asker.query(keys.sim_control(), SimControl(op="pause"), SimStatus)
        with pytest.raises(RemoteError, match="expected SimControl"):
            asker.query(keys.sim_control(), imu(0), SimStatus)
    assert node.metrics.snapshot().dropped == {
        "handler_error:ValueError": 1,
        "unexpected_schema": 1,
    }


def test_latest_only_skips_stale_samples(node, client):
    keys = Keys()
    seen: list[int] = []
    first = threading.Event()

    def slow(m: ImuSample) -> None:
        seen.append(m.seq)
        first.set()
        time.sleep(0.05)

    node.subscribe(keys.imu(), ImuSample, slow, latest_only=True)
    publisher = matched_publisher(client, keys.imu())
    publisher.put(encode(imu(0)))
    assert first.wait(10)
    for i in range(1, 101):
        publisher.put(encode(imu(i)))
    wait_for(lambda: seen and seen[-1] == 100, 10, "the newest sample")
    assert len(seen) < 20  # the rest were superseded while the handler was busy
    assert seen == sorted(seen)


def test_garbage_cannot_evict_the_newest_valid_sample(node, client):
    """A newest-wins input under a flood of garbage still gets the last valid sample: the
    garbage is looked at and counted, the good one handled, the older good ones superseded."""
    keys = Keys()
    seen: list[int] = []
    gate = threading.Event()
    started = threading.Event()

    def blocked(m: ImuSample) -> None:
        seen.append(m.seq)
        started.set()
        gate.wait(10)  # the handler is busy while the burst arrives

    node.subscribe(keys.imu(), ImuSample, blocked, latest_only=True)
    publisher = matched_publisher(client, keys.imu())
    publisher.put(encode(imu(0)))
    assert started.wait(10)
    for i in range(1, 4):
        publisher.put(encode(imu(i)))
    for _ in range(6):  # newer than every good sample, and fewer than the ring holds
        publisher.put(b"\x93\x01\x02")
    time.sleep(0.5)
    gate.set()
    wait_for(lambda: seen[-1:] == [3], 10, "the newest valid sample")
    dropped = node.metrics.snapshot().dropped
    assert sum(v for k, v in dropped.items() if k != "superseded") == 6, dropped
    assert dropped.get("superseded") == 2, dropped  # samples 1 and 2
    assert seen == [0, 3]


def test_an_input_thread_runs_at_the_nice_it_was_given(node, client):
    """``nice``: the input's thread at ordinary scheduling and that nice, whatever its creator's
    (deferrable work at realtime.BACKGROUND, after perception and rendering)."""
    keys = Keys()
    nices: list[int] = []

    def handler(_m: ImuSample) -> None:
        tid = threading.get_native_id()
        stat = Path(f"/proc/self/task/{tid}/stat").read_text().rsplit(")", 1)[1].split()
        nices.append(int(stat[16]))  # field 19 of stat: nice

    node.subscribe(keys.imu(), ImuSample, handler, latest_only=True, nice=BACKGROUND)
    publisher = matched_publisher(client, keys.imu())
    publisher.put(encode(imu(0)))
    wait_for(lambda: nices, 10, "the sample")
    assert nices == [BACKGROUND] and os.getpriority(os.PRIO_PROCESS, 0) == 0  # only that thread


def test_a_queued_input_runs_off_the_zenoh_callback_in_order(node, client):
    """``queue=N``: handled in arrival order on the input's own thread, not in Zenoh's."""
    keys = Keys()
    seen: list[int] = []
    threads: set[str] = set()

    def slow(m: ImuSample) -> None:
        threads.add(threading.current_thread().name)
        seen.append(m.seq)
        time.sleep(0.05)

    node.subscribe(keys.imu(), ImuSample, slow, queue=32)
    publisher = matched_publisher(client, keys.imu())
    for i in range(10):
        publisher.put(encode(imu(i)))
    wait_for(lambda: len(seen) == 10, 10, "every queued sample")
    assert seen == list(range(10))
    assert len(threads) == 1 and threads.pop().endswith(":slow")


def test_a_batched_input_gets_everything_that_waited_in_one_call(node, client):
    """``batch=True``: while the handler is busy, samples wait in the queue; the next call
    gets every valid one of them as a list, in order (garbage among them dropped, counted)."""
    keys = Keys()
    calls: list[list[int]] = []
    gate, started = threading.Event(), threading.Event()

    def handler(messages: list[ImuSample]) -> None:
        calls.append([m.seq for m in messages])
        started.set()
        gate.wait(10)

    node.subscribe(keys.imu(), ImuSample, handler, queue=8, batch=True)
    publisher = matched_publisher(client, keys.imu())
    publisher.put(encode(imu(0)))
    assert started.wait(10)
    for i in range(1, 5):
        publisher.put(encode(imu(i)))
        if i == 2:
            publisher.put(b"\x93\x01\x02")
    time.sleep(0.5)
    gate.set()
    wait_for(lambda: len(calls) == 2, 10, "the second call")
    assert calls == [[0], [1, 2, 3, 4]]
    assert sum(node.metrics.snapshot().dropped.values()) == 1
    with pytest.raises(ValueError):
        node.subscribe(keys.imu(), ImuSample, handler, batch=True)  # no queue


def test_an_input_undeclared_before_the_node_stops_taking_samples(node, client):
    """``subscribe`` and ``inbox`` return their subscription: ``undeclare()`` ends it (an
    input needed only for a while, e.g. the explorer's frames while a view is captured), and
    a queued input's thread ends with it; the node's other inputs go on."""
    keys = Keys()
    direct: list[int] = []
    queued: list[int] = []
    kept: list[int] = []
    subs = [
        node.subscribe(keys.imu(), ImuSample, lambda m: direct.append(m.seq)),
        node.subscribe(keys.imu(), ImuSample, lambda m: queued.append(m.seq), queue=4,
                       name="queued"),
        node.inbox(keys.imu(), ImuSample, size=4),
    ]  # fmt: skip
    node.subscribe(keys.imu(), ImuSample, lambda m: kept.append(m.seq))
    publisher = matched_publisher(client, keys.imu())
    publisher.put(encode(imu(0)))
    wait_for(lambda: direct == [0] and queued == [0] and kept == [0], 10, "the first sample")
    assert [m.seq for m in subs[2].take()] == [0]
    pumps = [t for t in threading.enumerate() if t.name.endswith(":queued")]
    assert len(pumps) == 1
    for sub in subs:
        sub.undeclare()
    sub.undeclare()  # twice: nothing happens
    pumps[0].join(5)
    assert not pumps[0].is_alive()
    publisher.put(encode(imu(1)))
    wait_for(lambda: kept == [0, 1], 10, "the second sample on the kept input")
    time.sleep(0.2)
    assert direct == [0] and queued == [0] and subs[2].take() == []
    assert len(node._subscribers) == 1


def test_an_inbox_gives_its_loop_the_valid_samples_in_order_and_counts_the_rest(node, client):
    """``Node.inbox``: no thread of its own; ``take()`` returns what came since the last call,
    valid ones in order, garbage counted; a ring found full is counted as ``inbox_full``."""
    keys = Keys()
    threads = threading.active_count()
    inbox = node.inbox(keys.imu(), ImuSample, size=8)
    assert threading.active_count() == threads
    witness = _witness(node, keys.imu())
    publisher = matched_publisher(client, keys.imu())
    for i in range(3):
        publisher.put(encode(imu(i)))
    publisher.put(b"\x93\x01\x02")
    publisher.put(encode(imu(3)))
    witness(5)
    assert [m.seq for m in inbox.take()] == [0, 1, 2, 3]
    assert inbox.take() == []
    assert node.metrics.snapshot().dropped == {"malformed": 1}
    for i in range(4, 20):  # twice what the ring holds: the oldest are overwritten
        publisher.put(encode(imu(i)))
    witness(5 + 16)
    assert [m.seq for m in inbox.take()] == list(range(12, 20))
    assert node.metrics.snapshot().dropped == {"malformed": 1, "inbox_full": 1}


def test_a_loop_taking_from_an_inbox_while_the_node_closes_ends_quietly(router):
    """close() undeclares the inputs first, then joins the threads: a loop inside ``take()``
    at that moment must end as it would on a closed input, not die with PyO3's "Already
    mutably borrowed" (the sim's physics loop did, at the end of a pipeline run; here 2 of 150
    closes raised it before the fix)."""
    errors: list[str] = []
    for i in range(400):
        settings = ServiceSettings(mode="client", connect=[router], multicast=False,
                                   instance=f"closing{i}")  # fmt: skip
        node = Node("closing", settings)
        inbox = node.inbox(Keys().imu(), ImuSample, size=8)

        def loop(node=node, inbox=inbox) -> None:
            try:
                while not node.stopping:
                    inbox.take()
            except Exception as e:  # what the test looks for
                errors.append(repr(e))

        node.start_thread(loop, "closing:loop")
        node.close()
    assert errors == []


def test_an_inbox_read_on_demand_decodes_only_the_newest_valid_sample(node, client):
    """``newest()``: garbage after the last good sample cannot hide it; the older samples are
    not decoded (counted in and as ``unread``); nothing new gives None."""
    keys = Keys()
    inbox = node.inbox(keys.imu(), ImuSample, size=16)
    witness = _witness(node, keys.imu())
    publisher = matched_publisher(client, keys.imu())
    for i in range(5):
        publisher.put(encode(imu(i)))
    publisher.put(b"\x00\x01garbage")
    publisher.put(b"\x00\x01garbage")
    witness(7)
    assert inbox.newest().seq == 4
    m = node.metrics.snapshot()
    assert m.messages_in[keys.imu()] == 7 and m.messages_valid[keys.imu()] == 1
    assert m.dropped == {"malformed": 2, "unread": 4}
    assert inbox.newest() is None


def _witness(node, key: str):
    """A plain subscriber beside the inbox in the node's session (outside its metrics):
    ``witness(n)`` waits until n samples have reached the session, and a moment more."""
    seen = []
    node._subscribers.append(node.session.declare_subscriber(key, lambda s: seen.append(1)))

    def wait(n: int) -> None:
        wait_for(lambda: len(seen) >= n, 10, f"{n} samples")
        time.sleep(0.2)

    return wait


def test_a_service_stops_on_ctrl_c_under_avs_up(router, procs):
    """Ctrl-C in ``avs up``'s terminal: SIGINT reaches every service (its process group),
    then the supervisor's SIGTERM right after. Each of ten nodes (a loop, an input, Zenoh's
    threads) stops within 5 s. With the stop event set in the signal handler and ``spin``
    waiting on it without a timeout, 7 in 20 never stopped."""
    import signal
    import subprocess

    from tests.conftest import avs_env

    hung = 0
    for _ in range(10):
        p = procs.python(
            [str(Path(__file__).parent / "procs" / "idle_node.py")],
            env=avs_env(router), stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert p.stdout.readline().strip() == "up"
        time.sleep(0.2)
        p.send_signal(signal.SIGINT)
        p.send_signal(signal.SIGTERM)
        try:
            assert p.wait(5) == 0
        except subprocess.TimeoutExpired:
            hung += 1
            p.kill()
            p.wait()
    assert hung == 0, f"{hung} of 10 nodes did not stop"


@pytest.mark.parametrize(("env", "ms"), [({}, 0.5), ({"AVS_SWITCH_INTERVAL_MS": "2"}, 2.0)])
def test_a_service_sets_the_interpreters_switch_interval(router, procs, env, ms):
    """Every service shortens CPython's switch interval (5 ms) to ``switch_interval_ms``: the
    longest a thread waits for the GIL another one holds, which a frame step waits at every
    compiled call and parallel region (benchmarks/gil_waits.py)."""
    import subprocess

    from tests.conftest import avs_env

    p = procs.python(
        [str(Path(__file__).parent / "procs" / "idle_node.py")],
        env={**avs_env(router), **env}, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert p.stdout.readline().strip() == "up"
    assert float(p.stdout.readline()) == pytest.approx(ms)


def test_a_stopping_service_finishes_the_handler_in_flight(router, client, procs):
    """SIGTERM while a handler runs: the handler finishes before the service closes what it
    writes to. With the service closed first (as run_node did), its write met a closed file
    and the message was dropped as a handler error: the scene memory lost the observation it
    was fusing (``write to closed file``) at every stop of a busy stack."""
    import signal
    import subprocess

    from schemas import ImuSample, encode
    from tests.conftest import avs_env, matched_publisher

    p = procs.python(
        [str(Path(__file__).parent / "procs" / "busy_node.py")],
        env=avs_env(router), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert p.stdout.readline().strip() == "up"
    pub = matched_publisher(client, Keys().imu())
    sample = ImuSample(seq=7, stamp=0.0, angular_velocity=(0, 0, 0),
                       linear_acceleration=(0, 0, 9.81), orientation=(1, 0, 0, 0))  # fmt: skip
    pub.put(encode(sample))
    assert p.stdout.readline().strip() == "handling"
    p.send_signal(signal.SIGTERM)
    out, err = p.communicate(timeout=10)
    assert p.returncode == 0, err
    assert out.split() == ["handled"], (out, err)
    assert "handler_error" not in err and "closed file" not in err, err
