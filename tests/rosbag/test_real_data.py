"""``benchmarks/real_data.py``: its bookkeeping (the pose the memory holds per frame, the level
planes of a model), and its core on the first frames of the real Kinect kitchen: replayed with
drift by ``avs replay-dataset`` into a real perception and scene memory (processes, over Zenoh)
with view registration on.

The recordings are read where they are (``../shared/data/real``, or ``AVS_REAL_DATA``), never
copied here; without them the test that needs them is skipped, saying where they come from."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from benchmarks.real_data import (
    DRIFT,
    drift_residual,
    grouped,
    level_planes,
    pose_errors,
    revisit_errors,
    revisits,
    run_recording,
)
from schemas import Obb, PlaneModel, PoseCorrection, Primitive, SceneModel
from services.adapters.dataset.drift import Drift, drift_transform
from services.adapters.dataset.formats import Intrinsics, Recording, read
from services.adapters.dataset.frames import DatasetFrames
from tests.real import REAL, needs_real

#: the kitchen test's bounds, measured 2026-12-05 with planar registration: the drifted run's
#: poses at most 1.0 mm from the still run's (the drift of the one or two frames since the
#: last registration; without registration 5.3 mm at frame 11), and 4.8 mm from the reference
#: at frame 11 (the still run's own 4.8 mm; full registration made it 13.7 mm)
DRIFT_RESIDUAL_MM = 2.0
POSE_ERROR_MM = 10.0


def _frames(n: int, drift: Drift) -> DatasetFrames:
    """``n`` frames 0.1 m apart along y, looking the same way, no images."""
    poses = []
    for k in range(n):
        T = np.eye(4)
        T[:3, 3] = (0.0, 0.1 * k, 1.2)
        poses.append(T)
    rec = Recording("tum", Path("."), [0.1 * k for k in range(n)], [], [], poses,
                    Intrinsics(0, 0, 1, 1, 0, 0), 1.0)  # fmt: skip
    return DatasetFrames(rec, drift=drift)


def _correction(seq: int, T: np.ndarray, accepted: bool = True, reason: str = "") -> PoseCorrection:
    return PoseCorrection(seq=seq, stamp=0.0, T_world_odom=T, camera="head_rgbd",
                          frame_seq=seq, accepted=accepted, reason=reason)  # fmt: skip


def test_the_pose_the_memory_holds_is_its_last_correction_times_the_carried_pose():
    """Frame 4's correction undoes its drift exactly: no error there; frames 5-6 carry it and
    err by one and two more frames of drift; before it, the full drift."""
    d = Drift(2.0, 0.0)
    frames = _frames(7, d)
    pivot = frames.pose(0)[:3, 3]
    corrections = [_correction(0, np.eye(4)), _correction(2, np.eye(4), False, "not_due"),
                   _correction(4, np.linalg.inv(drift_transform(4, d, pivot)))]  # fmt: skip
    got = pose_errors(frames, corrections)
    errors = [row[1] for row in got["per_frame"]]
    drift = [row[3] for row in got["per_frame"]]
    assert drift == pytest.approx([0, 2, 4, 6, 8, 10, 12], abs=1e-9)
    assert errors == pytest.approx([0, 2, 4, 6, 0, 2, 4], abs=1e-9)
    assert (got["pose_error_mm"], got["drift_error_mm"]) == (4.0, 12.0)
    assert (got["mapped"], got["registered"], got["refused"]) == (3, 1, 0)
    assert got["reasons"] == {"not_due": 1}


def test_the_drift_residual_compares_the_held_poses_frame_by_frame():
    """A still run whose registration moved every frame 5 mm off its reference (the depth and
    the reference disagree), and a drift run whose corrections land each frame on the still
    run's pose except the last two frames (one and two frames of drift): pose_error is 5 mm
    and more, the residual 0 until frame 4, then the drift since."""
    d = Drift(2.0, 0.0)
    off = np.eye(4)
    off[1, 3] = 0.005  # registration's view of the reference: 5 mm along y
    still = pose_errors(_frames(6, Drift(0.0, 0.0)), [_correction(0, off)])
    frames = _frames(6, d)
    pivot = frames.pose(0)[:3, 3]
    undo = off @ np.linalg.inv(drift_transform(4, d, pivot))
    drifted = pose_errors(frames, [_correction(0, off), _correction(4, undo)])
    got = drift_residual(drifted, still)
    assert got["drift_residual_per_frame_mm"] == pytest.approx([0, 2, 4, 6, 0, 2], abs=1e-6)
    assert (got["drift_residual_mm"], got["drift_residual_mm_max"]) == (2.0, 6.0)
    assert still["pose_error_mm"] == 5.0 and got["still_pose_error_mm"] == 5.0
    assert drifted["pose_error_mm"] == pytest.approx(math.hypot(5, 2), abs=0.05)
    assert got["same_frames"] == "no"  # frame 4 was integrated by one run only
    same = pose_errors(_frames(6, Drift(0.0, 0.0)), [_correction(0, off), _correction(4, off)])
    assert drift_residual(drifted, same)["same_frames"] == "yes"
    assert drift_residual(drifted, same)["drift_residual_mm"] == 2.0


def test_level_planes_are_the_large_level_ones():
    def plane(i: int, normal, z: float, side: float) -> Primitive:
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        obb = Obb(center=np.array([0.0, 0.0, z]), rotation=np.eye(3),
                  extent=np.array([side, side, 0.01]))  # fmt: skip
        return Primitive(id=i, model=PlaneModel(normal=n, d=-z * n[2]), obb=obb, inlier_count=10,
                         inliers=np.zeros((0, 3), np.float32))  # fmt: skip

    tilt = math.tan(math.radians(15))
    model = SceneModel(seq=0, stamp=0.0, model_version=1, n_views=1, fusion="sg", primitives=[
        plane(0, (0, 0, 1), 0.72, 1.0), plane(1, (0, 0, 1), 0.0, 3.0),
        plane(2, (0, 0, 1), 0.45, 0.2),  # too small
        plane(3, (tilt, 0, 1), 0.9, 1.0),  # 15° off level
        plane(4, (1, 0, 0), 1.0, 1.0),  # a wall
    ])  # fmt: skip
    assert level_planes(model) == [0.0, 0.72]
    assert grouped([0.0, 0.01, 0.02, 0.72, 0.44, 0.035, 0.74]) == [
        (0.01, 3),
        (0.035, 1),
        (0.44, 1),
        (0.73, 2),
    ]


def test_revisits_are_far_apart_frames_that_see_the_same_place():
    """Seven frames of a 1 m square of points: frame 4 sees it 0.6 m aside (41 % of either's
    points within 2 cm of the other's), frame 6 from 5 cm nearer. Of every 2nd frame, the
    pairs at least ``gap`` apart that overlap by ``overlap`` where the poses place them:
    frame 6 only once its pose says it was 5 cm nearer."""
    g = np.linspace(-0.5, 0.5, 41)
    square = np.column_stack([np.repeat(g, 41), np.tile(g, 41), np.ones(41 * 41)])
    clouds = [square] * 7
    clouds[4] = square + np.array([0.6, 0.0, 0.0])
    clouds[6] = square - np.array([0.0, 0.0, 0.05])
    poses = [np.eye(4) for _ in range(7)]
    assert revisits(clouds, poses, gap=2, overlap=0.6, at_most=10) == [(0, 2)]
    assert revisits(clouds, poses, gap=2, overlap=0.3, at_most=10) == [(0, 2), (0, 4), (2, 4)]
    assert revisits(clouds, poses, gap=4, overlap=0.3, at_most=10) == [(0, 4)]
    assert revisits(clouds, poses, gap=2, overlap=0.3, at_most=2) == [(0, 2), (2, 4)]
    poses[6][2, 3] = 0.05
    assert revisits(clouds, poses, gap=2, overlap=0.6, at_most=10) == [(0, 2), (0, 6), (2, 6)]


@needs_real
@pytest.mark.slow
def test_the_kitchen_reference_agrees_with_its_depth_where_the_camera_came_back():
    """redkitchen-a's reference poses against the depth alone (``revisit_errors``: frames
    42-62 seen again at 94-98): ~14 mm (measured 2026-12-05), the pairwise noise of Kinect v1
    depth; the same poses with twice the issue's drift (1 mm and 0.04° a frame) ~31 mm: the
    measure sees a walk of a few cm between two visits of a place, which registration's
    poses show (~50 mm, benchmarks/real_data.py)."""
    frames = DatasetFrames(read(REAL / "redkitchen-a"), drift=Drift(1.0, 0.04), colour=False)
    chosen = frames.indices()
    got = revisit_errors(frames, {
        "reference": [frames.pose(i) for i in chosen],
        "drift": [frames.published_pose(i, seq) for seq, i in enumerate(chosen)],
    })  # fmt: skip
    assert got["revisits"] >= 10
    assert got["revisit_mm_reference"] < 20.0, got
    assert got["revisit_mm_drift"] > got["revisit_mm_reference"] + 10.0, got


@needs_real
@pytest.mark.slow
def test_the_kitchen_replayed_with_drift_into_the_real_services(tmp_path):
    """12 frames (2 s) of redkitchen-a with 0.5 mm and 0.02° of drift a frame, and again
    without drift, both with (planar) registration on. Every frame is perceived and reaches
    the memory, whose model holds the floor (z = 0) and the table top (0.72 m: the level
    planes ``--up auto`` finds, tests/rosbag/test_dataset.py). Registration runs (every 0.5 s
    of the recording: frames 1, 4, 7, 10) and is accepted on the same frames in both runs; it
    undoes the drift: the drifted run's poses within DRIFT_RESIDUAL_MM of the still run's.
    Against the reference poses it is off by what registration makes of them without drift
    (the Kinect depth and the reference disagree: see benchmarks/real_data.py)."""
    kitchen = REAL / "redkitchen-a"
    still = run_recording(kitchen, tmp_path, registration=True, rate=0.25, limit=12,
                          tag="still", offsets=False)  # fmt: skip
    got = run_recording(kitchen, tmp_path, drift=DRIFT, registration=True, rate=0.25, limit=12,
                        tag="test")  # fmt: skip
    assert got["frames"] == got["observations"] == 12
    assert 0 < got["perception_ms"] < 2000
    assert got["primitives"] > 10 and got["plane"] > 0
    levels = got["level_planes_m"]
    assert any(abs(h) < 0.02 for h in levels) and any(0.70 < h < 0.75 for h in levels), levels
    assert 0.0 <= got["unstable_share"] <= 1.0
    # the drift the frames carried: 11 frames of 0.02° of yaw, ~0.5 mm a frame
    assert got["drift_error_deg"] == pytest.approx(0.22, abs=0.005)
    assert 4.0 < got["drift_error_mm"] < 7.0
    assert got["registered"] >= 3 and got["refused"] == 0, got["reasons"]
    assert len(got["per_frame"]) == 12
    residual = drift_residual(got, still)
    assert got["mapped"] == still["mapped"] == 12 and residual["same_frames"] == "yes"
    assert residual["drift_residual_mm_max"] < DRIFT_RESIDUAL_MM, residual
    assert got["pose_error_mm"] < POSE_ERROR_MM, got["per_frame"]
