"""The gaze service as a process against the sim as a process (real time, ARMAR-III in the
localization scene) over a loopback router: a manual gaze/target is held while the hip
swings (OKR on the foveal frames, their colour blobs on the ego-sphere), commands carry the IMU
stamp that caused them, and a silent IMU holds the head."""

from __future__ import annotations

import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from schemas import (
    EgoSphereSnapshot,
    GazeTarget,
    HeadCommand,
    JointState,
    Keys,
    RgbdFrame,
    ServiceMetrics,
    SimControl,
    SimStatus,
    decode,
    encode,
)
from services.common.robots import robot_mjcf
from services.gaze.kinematics import GazeKinematics
from tests.conftest import avs_env, liveliness_tokens, wait_for
from tests.scene_memory.builders import box, cylinder, observation

KEYS = Keys("armar3")
CUP = np.array([1.5, 0.15, 0.86])
#: the true gaze error over 6 s of the hip swing, real time on 2 cores with the sensor models:
#: RMS 0.05-0.34°, max 0.14-2.3° measured over five runs (scheduling stalls make the tail)
RMS_DEG, MAX_DEG = 0.5, 3.0


def control(client, **request) -> SimStatus:
    (reply,) = client.get(KEYS.sim_control(), payload=encode(SimControl(**request)), timeout=30)
    status = decode(reply.ok.payload.to_bytes(), SimStatus)
    assert status.ok, status.error
    return status


def start_sim_and_gaze(procs, client, router, name: str, sim_args: list[str], gaze_args: list[str]):
    """The sim (ARMAR-III, localization) and the gaze service as processes, instances
    sim-<name> and gaze-<name>; returns the gaze process once both are alive."""
    env = avs_env(router, MUJOCO_GL="egl", AVS_ROBOT="armar3")
    procs.python(["-m", "services.sim", "--instance", f"sim-{name}", "--scene", "localization",
                  *sim_args], env=env)  # fmt: skip
    gaze = procs.python(["-m", "services.gaze", "--instance", f"gaze-{name}", *gaze_args],
                        env=env)  # fmt: skip
    wanted = {KEYS.alive("sim", f"sim-{name}"), KEYS.alive("gaze", f"gaze-{name}")}
    wait_for(lambda: wanted <= liveliness_tokens(client, KEYS.alive()), 90, "sim and gaze")
    return gaze


def gaze_error_deg(T: np.ndarray, target: np.ndarray) -> float:
    """The angle between a camera's optical axis and the target (deg)."""
    to, z = target - T[:3, 3], T[:3, 2]
    return math.degrees(math.atan2(np.linalg.norm(np.cross(z, to)), z @ to))


def metrics_of(client, instance: str) -> ServiceMetrics:
    replies = [r.ok for r in client.get(KEYS.metrics("gaze", instance), timeout=5) if r.ok]
    return decode(replies[0].payload.to_bytes(), ServiceMetrics)


def metrics(client) -> ServiceMetrics:
    return metrics_of(client, "gaze-test")


@pytest.mark.timeout(180)
def test_gaze_node_holds_the_cup_while_the_hip_swings_and_holds_still_without_imu(
    router, client, procs
):
    # the robot's sensor models on: the gyro's noise and bias, encoders, 2 ms joint latency
    sim_args = ["--cameras", "left_foveal", "--fps", "10", "--sensors"]
    gaze = start_sim_and_gaze(procs, client, router, "test", sim_args,
                              ["--blob-camera", "left_foveal"])  # fmt: skip
    lock = threading.Lock()
    joints: list[JointState] = []
    commands: list[HeadCommand] = []
    egospheres: list[EgoSphereSnapshot] = []
    frames: list[RgbdFrame] = []

    def on(sample, kind, into):
        with lock:
            into.append(decode(sample.payload.to_bytes(), kind))

    subs = [
        client.declare_subscriber(KEYS.joints(), lambda s: on(s, JointState, joints)),
        client.declare_subscriber(KEYS.cmd_head(), lambda s: on(s, HeadCommand, commands)),
        client.declare_subscriber(KEYS.egosphere(), lambda s: on(s, EgoSphereSnapshot, egospheres)),
        client.declare_subscriber(KEYS.rgbd("left_foveal"), lambda s: on(s, RgbdFrame, frames)),
    ]
    target = client.declare_publisher(KEYS.gaze_target())
    seq = 0

    def aim(seconds: float) -> None:
        nonlocal seq
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            seq += 1
            target.put(encode(GazeTarget(seq=seq, stamp=time.time(), point=CUP,
                                         source="manual", priority=1.0, hold_s=2.0)))  # fmt: skip
            time.sleep(0.25)

    aim(3.0)  # fixate
    control(client, op="set_disturbance", joint="hip_yaw", amplitude=20.0, frequency=0.25)
    with lock:
        joints.clear()
        frames.clear()
    aim(6.0)  # the hip swings by ±12.7°
    with lock:
        window, cmds, seen = list(joints), list(commands), list(frames)
    # the sim's true camera pose of each frame (the platform stands, so odometry adds nothing)
    errors = np.array([gaze_error_deg(f.T_world_camera, CUP) for f in seen])
    hip = [float(js.position[js.names.index("hip_yaw")]) for js in window]
    print(f"over {len(errors)} frames: gaze error RMS {np.sqrt(np.mean(errors**2)):.3f}°, "
          f"max {errors.max():.3f}°; hip swing {math.degrees(np.ptp(hip)):.1f}°")  # fmt: skip
    assert len(window) > 500 and math.degrees(np.ptp(hip)) > 15 and len(seen) > 30
    assert np.sqrt(np.mean(errors**2)) < RMS_DEG and errors.max() < MAX_DEG
    gaze_cmds = [c for c in cmds if c.source == "gaze" and c.mode == "velocity"]
    # one per IMU sample taken: the newest each step, so on a loaded machine fewer (counted);
    # the sustained rate is benchmarks/gaze.py's to measure
    assert len(gaze_cmds) > 1500
    assert all(c.trigger_stamp is not None for c in gaze_cmds if np.any(c.values))
    m = metrics(client)
    assert m.extra["control_steps"] > 1500 and m.extra["holding"] == 0
    # OKR runs on the foveal frames; with the forward model right there is little slip to take
    assert m.messages_in.get(KEYS.rgbd("left_foveal"), 0) > 30
    assert 0 < m.extra["okr_offset_m"] < 0.01
    # the gyro's bias, estimated while the head was still (the model's: 0.1 °/s σ per axis)
    assert 0 < m.extra["gyro_bias_deg_s"] < 0.5
    assert m.extra["blobs"] >= 1  # the green cup (and the box's marks) on the ego-sphere
    with lock:
        snapshots = [e for e in egospheres if "blob" in e.sources]
    assert snapshots and len(snapshots[-1].saliency) == 2000  # gaze/egosphere, every 20th point
    assert snapshots[-1].saliency.max() > 0.05
    # the sim pauses: no IMU, so the head is held (one zero command) and the node says so
    control(client, op="pause")
    wait_for(lambda: metrics(client).extra.get("holding") == 1, 5, "gaze to hold the head")

    def last() -> HeadCommand:
        with lock:
            return commands[-1]

    # (the metrics' answer may overtake the zero command on its way to this subscriber)
    wait_for(lambda: not np.any(last().values), 5, "the zero command")
    held = len(commands)
    time.sleep(0.5)  # and nothing moves the head after it
    assert last().source == "gaze" and len(commands) == held
    for s in subs:
        s.undeclare()
    assert gaze.poll() is None


BOX = np.array([1.5, -0.15, 0.84])


@pytest.mark.timeout(180)
def test_without_a_target_the_gaze_goes_to_the_object_it_knows_least(router, client, procs):
    """Thesis 5.1: the cup has been localised twice (σ below the 1 cm task acuity: no
    saliency), the box once (σ above it): the ego-sphere's winner is the box, and the cup is
    never fixated (inhibition of return alone would take turns between two salient objects)."""
    cpu = max(os.sched_getaffinity(0))  # and pinned to one CPU (AVS_GAZE_CPUS), every thread
    gaze = start_sim_and_gaze(procs, client, router, "sel", ["--fps", "0"],
                              ["--select-every", "1.0", "--cpus", str(cpu)])  # fmt: skip
    threads = list(Path(f"/proc/{gaze.pid}/task").iterdir())
    assert len(threads) > 5 and all(os.sched_getaffinity(int(t.name)) == {cpu} for t in threads)
    states: list[JointState] = []
    sub = client.declare_subscriber(
        KEYS.joints(), lambda s: states.append(decode(s.payload.to_bytes(), JointState))
    )
    kin = GazeKinematics(robot_mjcf("armar3"), ["left_foveal"])

    def error(js: JointState, point: np.ndarray) -> float:
        kin.update(
            kin.configuration((0.0, 0.0, 0.0), dict(zip(js.names, js.position, strict=True)))
        )
        return math.degrees(kin.fixation("left_foveal", point)[2])

    wait_for(lambda: len(states) > 10, 10, "joint states")
    out = client.declare_publisher(KEYS.observation())
    T = np.eye(4)
    T[:3, 3] = [0.1, 0.05, 1.55]  # about where the head is
    cup, box_ = (
        cylinder(0, (1.5, 0.15, 0.81), 0.04, 0.1, np.pi),
        box(1, tuple(BOX), (0.08, 0.2, 0.16)),
    )
    # one observation: the cup found twice (two results fused in turn), the box once
    obs = observation(1, [cup, cup.model_copy(update={"id": 2}), box_], T=T)
    out.put(encode(obs.model_copy(update={"stamp": states[-1].stamp})))
    start = len(states)
    # (selections come every second; on a loaded machine the first saccades take a while)
    wait_for(lambda: error(states[-1], BOX) < 0.5, 20, "the gaze on the box")
    time.sleep(2.0)  # and a few selections more
    cup_errors = [error(js, CUP) for js in states[start::5]]
    print(f"closest to the cup: {min(cup_errors):.2f}°, first {cup_errors[0]:.2f}°")
    assert min(cup_errors) > 2.0  # never on the cup
    m = metrics_of(client, "gaze-sel")
    assert m.messages_in.get(KEYS.observation(), 0) == 1
    sub.undeclare()
