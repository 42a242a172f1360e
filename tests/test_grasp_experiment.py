"""The grasping-while-moving experiment (thesis 5.4.2): its parts (stereo localisation with its
covariance, the blob checks that refuse smeared and cut-off blobs, which frames count as the
gaze holding) and the command end to end, judged on MuJoCo's state: the cup grasped and the
image steadier stabilised at the defaults; no grasp where no green cup is to be seen; no grasp
where the servo closes and lifts but the cup stays put. (The servo alone:
tests/sim/test_arms.py.)"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from experiments.grasp import _K, MARKER, GraspRun, fixating
from experiments.grasp_vision import StereoCheck, find_blob, localise, silhouette_area
from services.common.arm import ArmKinematics
from services.common.robots import robot_mjcf
from services.gaze.kinematics import HEAD_JOINTS, GazeKinematics
from services.gaze.stabiliser import GazeStabiliser, StabiliserConfig
from services.sim.render import CameraRenderer
from services.sim.robots import ARMAR3
from services.sim.world import World
from tests.conftest import ROOT


def test_stereo_localises_the_hand_marker_within_its_covariance() -> None:
    """The foveal pair looking at the hand's red ball: the triangulated point is within a
    millimetre of the ball's centre, and within three σ of its own covariance."""
    world = World("grasping", ARMAR3)
    world.place(base=(0.0, -2.0, 0.0), l_shoulder_pitch=-1.2, l_elbow=-0.9, l_shoulder_roll=0.1)
    names, q, _ = world.joint_state()
    marker = ArmKinematics("armar3", "left").marker(dict(zip(names, q, strict=True)),
                                                    world.base_pose()[:3])  # fmt: skip
    cams = ["left_foveal", "right_foveal"]
    stab = GazeStabiliser(
        GazeKinematics(robot_mjcf("armar3"), cams),
        StabiliserConfig(HEAD_JOINTS["armar3"], cams, speed=ARMAR3.joint_speed),
    )
    for _ in range(1500):  # both foveal cameras onto the ball (vergence), as the gaze does
        names, q, qd = world.joint_state()
        x, y, yaw, vx, vy, wz = world.base_pose()
        cmd = stab.command(
            marker,
            (x, y, yaw),
            (vx, vy, wz),
            dict(zip(names, q, strict=True)),
            dict(zip(names, qd, strict=True)),
            world.imu()[0],
            world.time,
        )
        world.command_joints(list(cmd.velocity), "velocity", np.array([*cmd.velocity.values()]))
        world.step()
    assert max(cmd.error_rad.values()) < math.radians(0.1)
    renderer = CameraRenderer(world.model, 640, 480)
    blobs, poses = [], []
    for cam in ("left_foveal", "right_foveal"):
        renderer.snapshot(world.data, world.cameras[cam])
        blobs.append(find_blob(renderer.render(depth=False)[0], "red"))
        poses.append(world.T_world_camera(cam))
    renderer.close()
    check = StereoCheck()
    assert check.accepts(*blobs)
    (KL, _), (KR, _) = _K(world, "left_foveal"), _K(world, "right_foveal")
    p, S, gap = localise(blobs[0].centre, blobs[1].centre, KL, KR, *poses)
    model = tuple(
        silhouette_area("sphere", MARKER, p, T, K) for T, K in zip(poses, (KL, KR), strict=True)
    )
    assert all(abs(b.area / a - 1) < 0.05 for b, a in zip(blobs, model, strict=True))
    assert check.accepts(*blobs, gap, model)
    e = p - marker
    assert np.linalg.norm(e) < 1e-3
    assert e @ np.linalg.solve(S, e) < 9 * 3
    assert 1e-4 < np.linalg.det(S) ** (1 / 6) < 3e-3  # σ (Eq. 5.2): sub-millimetre to mm


def _disc(shift: int = 0, centre=(320, 240)) -> np.ndarray:
    img = np.full((480, 640, 3), 200, np.uint8)
    out = np.zeros_like(img, np.float32)
    steps = max(1, shift)
    for k in range(steps):  # a disc moving ``shift`` px during the exposure
        frame = img.copy()
        cv2.circle(frame, (centre[0] + k, centre[1]), 30, (20, 180, 40), -1)
        out += frame
    return (out / steps).astype(np.uint8)


def test_blob_checks_refuse_smeared_and_cut_blobs() -> None:
    check = StereoCheck()
    sharp = find_blob(_disc(), "green")
    assert sharp is not None and abs(sharp.area - math.pi * 30**2) < 150
    assert check.accepts(sharp, sharp)
    smeared = find_blob(_disc(shift=120), "green")  # washed out: what is left is smaller
    assert smeared is not None and smeared.area < 0.6 * sharp.area
    assert check.accepts(smeared, smeared)  # a pair alike, but not the object's size
    assert not check.accepts(smeared, smeared, expected=(sharp.area, sharp.area))
    assert check.accepts(sharp, sharp, expected=(sharp.area, sharp.area))
    cut = find_blob(_disc(centre=(10, 240)), "green")
    assert cut is not None and cut.touches_border and not check.accepts(cut, cut)
    small = find_blob(_disc(), "green")
    assert not check.accepts(sharp, small.__class__(small.area / 2, small.centre, 0.8, False))
    assert not check.accepts(sharp, sharp, gap=0.05)  # rays that do not meet


def test_fixating_leaves_out_the_gaze_shifts() -> None:
    run = GraspRun(times=[0.1 * k for k in range(21)])
    run.targets = [(0.5, "hand"), (1.5, "cup")]
    keep = fixating(run)
    t = np.array(run.times[1:])
    assert keep.shape == t.shape
    assert not keep[(t >= 0.5) & (t < 0.85)].any() and not keep[(t >= 1.5) & (t < 1.85)].any()
    assert keep[t < 0.45].all() and keep[(t > 0.9) & (t < 1.45)].all()


# -- end to end: the command as a user runs it, judged on MuJoCo's state -------------------------

SCENE = ROOT / "services" / "sim" / "scenes" / "grasping.xml"
CUP = '<body name="cup" pos="3.0 0.53 0.9" childclass="object">'


def _variant(where: Path, name: str, old: str, new: str) -> Path:
    """The grasping scene with one thing changed (a scene file, as a user would write one)."""
    text = SCENE.read_text()
    assert text.count(old) == 1, old
    path = where / f"{name}.xml"
    path.write_text(text.replace(old, new))
    return path


def _no_green_cup(where: Path) -> list[str]:
    """The cup on the table is white: nothing the robot looks for is there. 16 s: the platform
    carries the cup through the arm's reach (0.45 to 0.05 m ahead of it) from 12.4 to 15.1 s,
    where the defaults grasp it (the fingers close at 13 s)."""
    scene = _variant(where, "white_cup", 'rgba="0.1 0.7 0.15 1"', 'rgba="0.9 0.9 0.9 1"')
    return ["--scene", str(scene), "--duration", "16"]


def _screwed_cup(where: Path) -> list[str]:
    """The cup is screwed to the table (no free joint): seen, reached, closed on, not lifted."""
    return ["--scene", str(_variant(where, "screwed_cup", f"{CUP}\n      <freejoint/>", CUP))]


#: the end-to-end tests and their runs' arguments (seed 0, the sensor models on: the defaults)
EXPERIMENTS = {
    "test_grasp_experiment_grasps_the_cup_and_stabilising_steadies_the_image": (
        lambda where: ["--compare", "--jobs", "2"]
    ),
    "test_the_servo_waits_while_the_cup_is_never_localised": _no_green_cup,
    "test_grasped_is_judged_by_mujoco_not_by_the_servo": _screwed_cup,
}


@pytest.fixture(scope="module")
def experiments(request, tmp_path_factory):
    """The runs of the end-to-end tests selected, all started at once (a run keeps one core
    busy; side by side they share the machine's cores instead of queueing): test name →
    (process, its output directory, its stdout file)."""
    where = tmp_path_factory.mktemp("grasp")
    wanted = {item.name for item in request.session.items}
    runs = {}
    for name, arguments in EXPERIMENTS.items():
        if name not in wanted:
            continue
        out = where / name
        log = where / f"{name}.log"
        with log.open("w") as stdout, (where / f"{name}.err").open("w") as stderr:
            command = [sys.executable, "-m", "avs.cli", "grasp-experiment", *arguments(where)]
            process = subprocess.Popen(
                [*command, "--out", str(out)], stdout=stdout, stderr=stderr,
                start_new_session=True,
            )  # fmt: skip
        runs[name] = (process, out, log)
    yield runs
    for process, _, _ in runs.values():
        if process.poll() is None:  # a test failed before its run ended: the run's workers too
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _finished(run: tuple[subprocess.Popen, Path, Path]) -> tuple[str, Path]:
    """(stdout, output directory) of a test's run, once it has ended."""
    process, out, log = run
    code = process.wait()
    assert code == 0, log.with_suffix(".err").read_text()[-3000:]
    return log.read_text(), out


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_grasp_experiment_grasps_the_cup_and_stabilising_steadies_the_image(
    experiments, request
) -> None:
    """``avs grasp-experiment --compare`` at its defaults (seed 0, 24 s at most, the sensor
    models on): stabilised, the cup ends lifted ≥ 5 cm off the table and stays within 3 cm of
    the grasp site between the fingers over the run's last 2 s, the 2 s the robot carries it
    while driving on (MuJoCo's state, whatever the servo's phase says); the flow error while
    the gaze holds a target is at least 40 % lower than unstabilised (seed 0 measured 3.40 →
    1.58 deg/s, −53 %). Also the command's outputs: both modes' metrics, the three figures and
    Table 5.1's layout."""
    stdout, out = _finished(experiments[request.node.name])
    metrics = json.loads((out / "metrics.json").read_text())
    on, off = metrics["stabilised"], metrics["unstabilised"]
    assert on["lift_m"] >= 0.05, on["lift_m"]
    assert on["hold_m"] <= 0.03, on["hold_m"]
    assert on["grasped"] is True
    assert on["flow_rmse_deg_s"]["mean"] < 0.6 * off["flow_rmse_deg_s"]["mean"]
    assert "flow RMSE mean (deg/s)" in stdout and "decrease" in stdout
    for m in (on, off):
        assert set(m["flow_rmse_deg_s"]) == {"mean", "std", "max"}
        assert {"first_localised_s", "uncertainty", "phases", "gaze_shifts"} <= set(m)
    for name in ("uncertainty.png", "flow.png", "frames.png"):
        assert (out / name).stat().st_size > 5000


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_the_servo_waits_while_the_cup_is_never_localised(experiments, request) -> None:
    """A white cup where the green one stood: nothing on the table is what the robot looks
    for. While the platform drives the cup through the arm's reach, the cup is never localised,
    the servo never leaves its waiting phase, the fingers stay open (MuJoCo's finger joints:
    under 5 % of their travel), the cup stays where it stood (within 5 mm) and ``grasped`` is
    false."""
    _, out = _finished(experiments[request.node.name])
    m = json.loads((out / "metrics.json").read_text())
    assert m["first_localised_s"] is None and m["uncertainty"] == []
    assert [p for _, p in m["phases"]] == ["wait"]
    assert m["gripper_max"] < 0.05, m["gripper_max"]
    assert abs(m["lift_m"]) < 0.005, m["lift_m"]
    assert m["grasped"] is False


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_grasped_is_judged_by_mujoco_not_by_the_servo(experiments, request) -> None:
    """The cup screwed to the table: seen, reached and closed on, and the servo goes through
    closing, lifting and done as it does on a free cup; but the cup does not rise, so
    ``grasped`` is false (the servo's phase would have said true)."""
    _, out = _finished(experiments[request.node.name])
    m = json.loads((out / "metrics.json").read_text())
    assert [p for _, p in m["phases"]][-3:] == ["close", "lift", "done"]
    assert m["gripper_max"] > 0.3, m["gripper_max"]  # the fingers met the cup
    assert abs(m["lift_m"]) < 0.001, m["lift_m"]
    assert m["grasped"] is False
