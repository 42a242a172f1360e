"""The sim as a process over Zenoh: lockstep is repeatable bit for bit, commands and streams go
through the wire, ground truth is served, and a recording replays the same messages."""

from __future__ import annotations

import hashlib
import subprocess
import threading
import time
from collections import defaultdict

import numpy as np
import pytest
import zenoh
from mcap.reader import make_reader

from schemas import (
    BaseGoal,
    BasePose,
    GroundTruth,
    GroundTruthQuery,
    HeadCommand,
    ImuSample,
    JointState,
    Keys,
    Message,
    RgbdFrame,
    SimControl,
    SimStatus,
    decode,
    encode,
)
from schemas.export import json_schema_text
from services.common.poses import pose_difference
from services.common.robots import robot_mjcf
from services.explorer.node import await_commands
from services.gaze.kinematics import GazeKinematics
from tests.conftest import avs_env, liveliness_tokens, matched_publisher, wait_for

KEYS = Keys()


def start_sim(procs, router: str, *args: str, instance: str = "sim-test") -> subprocess.Popen:
    p = procs.python(
        ["-m", "services.sim", "--instance", instance, *args],
        env=avs_env(router, MUJOCO_GL="egl"),
    )
    return p


def wait_alive(client: zenoh.Session, instance: str, proc: subprocess.Popen) -> None:
    wait_for(
        lambda: (
            proc.poll() is not None
            or KEYS.alive("sim", instance) in liveliness_tokens(client, KEYS.alive())
        ),
        60,
        "the sim to come up",
    )
    assert proc.poll() is None, "the sim exited"


def control(client: zenoh.Session, timeout: float = 60.0, **request) -> SimStatus:
    replies = list(
        client.get(KEYS.sim_control(), payload=encode(SimControl(**request)), timeout=timeout)
    )
    assert len(replies) == 1 and replies[0].ok, replies
    status = decode(replies[0].ok.payload.to_bytes(), SimStatus)
    assert status.ok, status.error
    return status


class Collector:
    def __init__(self, client: zenoh.Session, *keys: str) -> None:
        self.items: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.subs = [client.declare_subscriber(key, self._on) for key in keys]

    def close(self) -> None:
        for s in self.subs:
            s.undeclare()

    def _on(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.items.append((str(sample.key_expr), sample.payload.to_bytes()))

    def count(self) -> int:
        """How many samples arrived. Cheap, for polling: decoding every sample at each poll
        held the GIL for 100+ ms at 2,000 samples, against the in-process router's deliveries."""
        with self.lock:
            return len(self.items)

    def messages(self, kind: type[Message] = Message) -> list:
        with self.lock:
            payloads = [p for _, p in self.items]
        return [m for m in map(decode, payloads) if isinstance(m, kind)]


def _frame_hashes(client, procs, router, seed: int, instance: str) -> list[str]:
    sim = start_sim(
        procs,
        router,
        "--lockstep",
        "--scene",
        "tabletop_clutter",
        "--seed",
        str(seed),
        instance=instance,
    )
    wait_alive(client, instance, sim)
    frames = Collector(client, KEYS.rgbd("*"))
    hashes = []
    control(client, op="reset", seed=seed)
    for n in (200, 150, 1):
        control(client, op="step", n=n)
        control(client, op="render")
        wait_for(lambda: frames.count() == len(hashes) + 1, 30, "the frame")
        f: RgbdFrame = frames.messages()[-1]
        hashes.append(
            hashlib.sha256(
                f.rgb.tobytes() + f.depth.tobytes() + f.T_world_camera.tobytes()
            ).hexdigest()
        )
    frames.close()
    sim.terminate()
    assert sim.wait(30) == 0
    return hashes


def test_lockstep_runs_with_one_seed_give_identical_frames(client, router, procs):
    first = _frame_hashes(client, procs, router, seed=11, instance="ls-a")
    second = _frame_hashes(client, procs, router, seed=11, instance="ls-b")
    assert first == second
    other = _frame_hashes(client, procs, router, seed=12, instance="ls-c")
    assert other != first  # the depth noise follows the seed


def test_commands_and_streams_over_zenoh(client, router, procs):
    sim = start_sim(procs, router, "--lockstep", "--scene", "tabletop_clutter", instance="cmd")
    wait_alive(client, "cmd", sim)
    imu, joints, base = (
        Collector(client, k) for k in (KEYS.imu(), KEYS.joints(), KEYS.base_state())
    )
    goal = matched_publisher(client, KEYS.cmd_base(), timeout=30)
    head = matched_publisher(client, KEYS.cmd_head(), timeout=30)
    assert control(client, op="status").applied == {}
    # a driver that waits for the planner's commands of a step names what did not come
    status = lambda: control(client, op="status")  # noqa: E731
    with pytest.raises(TimeoutError, match=r"base/head commands of step 7 after 0.2 s"):
        await_commands(status, 7, ("base", "head"), timeout=0.2)
    goal.put(encode(BaseGoal(seq=7, goal_id="g", x=-0.3, y=0.2, yaw=0.5)))
    head.put(
        encode(
            HeadCommand(
                seq=7, names=["neck_yaw", "wrist"], mode="position", values=np.array([0.3, 1.0])
            )
        )
    )
    head.put(b"not a command")
    await_commands(status, 7, ("base", "head"))  # ... and goes on once applied
    wait_for(lambda: _metric_drops(client, "cmd") >= 2, 30, "the sim to take the commands")
    assert control(client, op="status").applied == {"base": 7, "head": 7}
    status = control(client, op="step", n=4000)
    assert status.sim_time == pytest.approx(4.0, abs=1e-6)
    # the reply names the newest sample of each stream, for a driver to wait for
    assert status.published == {"imu": 3999, "joints": 799, "base": 799}
    # a billion steps would hold the sim for hours: refused before any work, naming the limit
    huge = SimControl.model_construct(**{**SimControl(op="step").model_dump(), "n": 10**9})
    (reply,) = client.get(KEYS.sim_control(), payload=encode(huge), timeout=10)
    assert (
        reply.err is not None
        and "less than or equal to 10000" in reply.err.payload.to_bytes().decode(errors="replace")
    )
    assert control(client, op="status").sim_time == pytest.approx(4.0, abs=1e-6)
    wait_for(lambda: imu.count() >= 4000 and base.count() >= 800, 30, "the streams")
    samples: list[ImuSample] = imu.messages()
    assert len(samples) == 4000  # 1 kHz in sim time
    assert [s.seq for s in samples] == list(range(4000))
    poses: list[BasePose] = base.messages()
    assert len(poses) == 800  # 200 Hz
    assert poses[-1].goal_status == "reached" and poses[-1].goal_id == "g"
    assert (poses[-1].x, poses[-1].y) == pytest.approx((-0.3, 0.2), abs=0.02)
    state: JointState = joints.messages()[-1]
    assert state.position[state.names.index("neck_yaw")] == pytest.approx(0.3, abs=0.01)
    drops = _metrics(client, "cmd").dropped
    assert drops.get("unknown_joint") == 1 and drops.get("malformed") == 1


def _metrics(client, instance):
    from schemas import ServiceMetrics

    (reply,) = [r.ok for r in client.get(KEYS.metrics("sim", instance), timeout=10) if r.ok]
    return decode(reply.payload.to_bytes(), ServiceMetrics)


def _metric_drops(client, instance) -> int:
    return sum(_metrics(client, instance).dropped.values())


def test_ground_truth_queryable(client, router, procs):
    sim = start_sim(procs, router, "--lockstep", "--scene", "tabletop_occluded", instance="gt")
    wait_alive(client, "gt", sim)
    replies = list(client.get(KEYS.ground_truth(), payload=encode(GroundTruthQuery()), timeout=60))
    gt = decode(replies[0].ok.payload.to_bytes(), GroundTruth)
    assert ("box_base", "cylinder_top") in gt.support_edges
    assert ("table", "cylinder_top") in gt.support_closure and (
        "table",
        "cylinder_top",
    ) not in gt.support_edges
    assert {o.name for o in gt.objects} >= {
        "table",
        "floor",
        "box_front",
        "box_base",
        "cylinder_top",
        "cup",
    }
    assert gt.segmentation.shape == (480, 640) and gt.camera == "head_rgbd"
    seen = {gt.labels[i] for i in np.unique(gt.segmentation) if i >= 0}
    assert {"table", "box_front", "cylinder_top", "cup"} <= seen and "box_base" not in seen
    # without the sensor models the robot believes the truth: a frame's camera pose is it
    frames = Collector(client, KEYS.rgbd("head_rgbd"))
    control(client, op="render")
    wait_for(lambda: frames.count() == 1, 30, "the frame")
    (frame,) = frames.messages(RgbdFrame)
    assert gt.T_world_odom is None
    assert np.abs(frame.T_world_camera - gt.T_world_camera).max() < 1e-9


def test_recording_replays_the_same_messages_in_the_same_order(client, router, procs, tmp_path):
    sim = start_sim(
        procs,
        router,
        "--lockstep",
        "--scene",
        "tabletop_clutter",
        "--width",
        "160",
        "--height",
        "120",
        instance="rec",
    )
    wait_alive(client, "rec", sim)
    out = tmp_path / "run.mcap"
    sent = 300 + 3 * 20 * 2 + 3
    # it stops by itself once it has every message: a Ctrl-C as soon as this process had them
    # all lost one still on its way to the recorder (1 in ~20 runs under load)
    recorder = procs.python(
        ["-m", "avs.cli", "record", "sensors/**", "state/**", "--out", str(out),
         "--count", str(sent)],
        env=avs_env(router),
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    # the recorder is a plain session: its subscription is in place once a publisher on one of
    # its keys matches (nothing else subscribes to this one yet)
    probe = client.declare_publisher(KEYS.key("state/probe"))
    wait_for(lambda: probe.matching_status.matching, 30, "the recorder's subscription")
    probe.undeclare()
    streams = ("avs/armar6/sensors/**", "avs/armar6/state/**")
    original = Collector(client, *streams)
    for _ in range(3):
        control(client, op="step", n=100)
        control(client, op="render")
    wait_for(lambda: len(original.items) == sent, 30, "the original streams")
    assert recorder.wait(30) == 0
    sim.terminate()
    sim.wait(30)
    original.close()

    # the mcap package's reader opens it: a msgpack channel per key, with the message's schema
    with open(out, "rb") as f:
        summary = make_reader(f).get_summary()
    assert summary.statistics.message_count == len(original.items)
    topics = {str(k) for k, _ in original.items}
    assert {c.topic for c in summary.channels.values()} == topics
    assert len(summary.channels) == len(topics)  # one type per key here
    for cid, channel in summary.channels.items():
        schema = summary.schemas[channel.schema_id]
        sent = next(decode(p) for k, p in original.items if k == channel.topic)
        assert (channel.message_encoding, schema.encoding) == ("msgpack", "jsonschema")
        assert schema.name == sent.SCHEMA and schema.data.decode() == json_schema_text(sent.SCHEMA)
        assert summary.statistics.channel_message_counts[cid] == sum(
            k == channel.topic for k, _ in original.items
        )

    replayed = Collector(client, *streams)
    replay = start_sim(procs, router, "--replay", str(out), "--speed", "5", instance="replay")
    assert replay.wait(60) == 0
    by_key_original, by_key_replayed = defaultdict(list), defaultdict(list)
    for key, payload in original.items:
        by_key_original[key].append(decode(payload))
    for key, payload in replayed.items:
        by_key_replayed[key].append(decode(payload))
    assert sorted(by_key_replayed) == sorted(by_key_original)
    for key in by_key_original:
        assert by_key_replayed[key] == by_key_original[key], key

    # Ctrl-C ends a recording with a whole file (its summary written)
    idle = tmp_path / "idle.mcap"
    stopped = procs.python(["-m", "avs.cli", "record", "idle/**", "--out", str(idle)],
                           env=avs_env(router), stderr=subprocess.DEVNULL)  # fmt: skip
    probe = client.declare_publisher(KEYS.key("idle/probe"))  # no one else subscribes to it
    wait_for(lambda: probe.matching_status.matching, 30, "the second recorder's subscription")
    probe.undeclare()
    stopped.send_signal(2)
    assert stopped.wait(30) == 0
    with open(idle, "rb") as f:
        assert make_reader(f).get_summary().statistics.message_count == 0


def test_sensor_models_over_zenoh(client, router, procs):
    """With ``--sensors`` the streams are what a robot measures: a still head's gyro scatters
    with the noise density, joint states come out their latency after the instant they are
    stamped with, on the encoders' grid, and state/base is the odometry's belief, which the
    ground truth relates to the true pose (T_world_odom) after a drive."""
    from services.sim.sensors import SensorSpec

    spec = SensorSpec()
    sim = start_sim(procs, router, "--lockstep", "--sensors", "--scene", "tabletop_clutter",
                    instance="sensors")  # fmt: skip
    wait_alive(client, "sensors", sim)
    imu, joints, base = (
        Collector(client, k) for k in (KEYS.imu(), KEYS.joints(), KEYS.base_state())
    )
    status = control(client, op="step", n=2000)  # still
    # the joint state measured at 2.000 s (seq 399) is not out yet
    assert status.published == {"imu": 1999, "joints": 398, "base": 399}
    wait_for(lambda: imu.count() >= 2000, 30, "the IMU", state=imu.count)
    gyro = np.array([s.angular_velocity for s in imu.messages()])
    density = np.diff(gyro, axis=0).std(axis=0) / np.sqrt(2) * np.sqrt(1e-3)
    assert np.allclose(density, spec.gyro_noise_density, rtol=0.1), density
    states: list[JointState] = joints.messages()
    # 200 Hz, each out 2 ms after its stamp: the one measured at 2.000 s is still on its way
    assert len(states) == 399 and states[-1].stamp == pytest.approx(1.995, abs=1e-9)
    steps = np.array([s.position for s in states]) / spec.encoder_resolution
    assert np.allclose(steps, np.round(steps), atol=1e-6)

    goal = matched_publisher(client, KEYS.cmd_base(), timeout=30)
    goal.put(encode(BaseGoal(goal_id="g", x=-0.8, y=0.0, yaw=0.0)))
    # the goal is taken before the steps: a query may overtake a put, and the steps hold the
    # sim until they are done (its drop of the bad message after the goal tells it was taken)
    goal.put(b"not a command")
    wait_for(lambda: _metric_drops(client, "sensors") >= 1, 30, "the sim to take the goal")
    control(client, op="step", n=6000)
    wait_for(lambda: base.count() >= 1600, 30, "the base states", state=base.count)
    believed: BasePose = base.messages()[-1]
    (reply,) = client.get(
        KEYS.ground_truth(), payload=encode(GroundTruthQuery(segmentation=False)), timeout=30
    )
    gt = decode(reply.ok.payload.to_bytes(), GroundTruth)
    assert gt.T_world_odom is not None and gt.T_world_camera is not None
    # the odometry believes it reached the goal; the truth is short of it by the scale error
    assert (believed.x, believed.y) == pytest.approx((-0.8, 0.0), abs=0.02)
    drift = np.linalg.norm(gt.T_world_odom[:2, 3])
    assert 0.003 < drift < 0.03, drift  # ~1.5 % of the ~0.9 m driven

    # a frame carries the camera pose the robot believes: the kinematics (pinocchio's, here)
    # of its own joint positions, which are the joint state of its instant as the encoders
    # read it, with the platform where the odometry's state of that instant says
    frames = Collector(client, KEYS.rgbd("head_rgbd"))
    control(client, op="render")
    control(client, op="step", n=10)  # the joint state of the frame's instant comes out
    wait_for(lambda: frames.count() == 1 and joints.count() >= 1601, 30, "the frame")
    (frame,) = frames.messages(RgbdFrame)
    (state,) = [s for s in joints.messages() if s.stamp == frame.stamp]
    (odometry,) = [b for b in base.messages() if b.stamp == frame.stamp]
    assert frame.joint_names == state.names
    assert np.array_equal(frame.joint_positions, state.position)
    kin = GazeKinematics(robot_mjcf("armar6"), ["head_rgbd"])
    kin.update(kin.configuration((odometry.x, odometry.y, odometry.yaw),
                                 dict(zip(state.names, state.position, strict=True))))  # fmt: skip
    assert np.abs(frame.T_world_camera - kin.camera_pose("head_rgbd")).max() < 1e-9
    # ... so it is the truth moved by the odometry's drift (gt's T_world_odom, at rest since)
    # and turned by the encoders' error (under 0.05°: 2.3e-4 rad of resolution, 1e-4 noise)
    drifted = gt.T_world_odom @ gt.T_world_camera
    moved_m, turned_deg = pose_difference(frame.T_world_camera, drifted)
    assert moved_m < 2e-4 and 0 < turned_deg < 0.05, (moved_m, turned_deg)
    assert pose_difference(frame.T_world_camera, gt.T_world_camera)[0] > 0.003


def test_lockstep_streams_wait_for_a_stalled_subscriber(procs, tmp_path):
    """In lockstep nothing is late, so nothing may be lost: a subscriber process that is
    stopped (SIGSTOP) for 2 s while the sim steps, behind 64 KB socket buffers so the backlog
    cannot hide in them, still receives every IMU sample, in order. On the key table's
    drop-on-congestion QoS it got 1 in 10. The router is a process of its own too, so nothing
    this test process ran before shares its Zenoh threads."""
    import json
    import signal
    import socket

    from tests.conftest import free_port, session_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    config = tmp_path / "router.json5"
    config.write_text(json.dumps({
        "listen": {"endpoints": [endpoint]},
        "transport": {"link": {"tcp": {"so_sndbuf": 65536, "so_rcvbuf": 65536}}},
    }))  # fmt: skip
    procs.python(["-m", "avs.router", "-c", str(config)], env=avs_env(endpoint))
    port = int(endpoint.rsplit(":", 1)[1])

    def listening() -> bool:
        with socket.socket() as s:
            return s.connect_ex(("127.0.0.1", port)) == 0

    wait_for(listening, 30, "the router")
    with zenoh.open(session_config("client", connect=[endpoint])) as client:
        sim = start_sim(procs, endpoint, "--lockstep", "--scene", "tabletop_clutter",
                        instance="stall")  # fmt: skip
        wait_alive(client, "stall", sim)
        stalled = procs.python(
            ["tests/procs/count_imu.py", endpoint, "5000"],
            env=avs_env(endpoint), stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        assert stalled.stdout.readline().strip() == "subscribed"
        stalled.send_signal(signal.SIGSTOP)
        resume = threading.Timer(2.0, stalled.send_signal, (signal.SIGCONT,))
        resume.start()
        t0 = time.monotonic()
        status = control(client, op="step", n=5000)
        resume.join()
        assert status.steps == 5000
        received = json.loads(stalled.communicate(timeout=60)[0].splitlines()[-1])
        assert received["errors"] == []
        assert received["seqs"] == list(range(5000)), len(received["seqs"])
        # the sim waited for the stopped subscriber rather than running ahead
        assert time.monotonic() - t0 > 1.5
        sim.terminate()
        assert sim.wait(30) == 0
