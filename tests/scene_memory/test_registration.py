"""View registration (A.5): ICP takes a frame whose odometry pose is off by 5 cm and 3° back to
its true pose against the map of the other views (planar: a platform's drift in the ground
plane and yaw; full: any direction and axis); a blank wall, which fits any sliding along it,
keeps its prior and says why."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas import CameraIntrinsics, Keys, PoseCorrection, decode, encode
from services.scene_memory.correction_filter import OdometryNoise
from services.scene_memory.memory import INCONSISTENT, NOT_DUE, MemoryConfig, SceneMemory
from services.scene_memory.occupancy import OccupancyConfig
from services.scene_memory.registration import (
    RegistrationConfig,
    camera_points,
    moved,
    pose_difference,
    register,
)
from tests.conftest import avs_env, matched_publisher, wait_for
from tests.scene_memory.views import BOUNDS_MAX, BOUNDS_MIN, VOXEL, reference


def rotation(axis: np.ndarray, degrees: float) -> np.ndarray:
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    t = math.radians(degrees)
    return np.eye(3) + math.sin(t) * K + (1 - math.cos(t)) * K @ K


def perturbed(T: np.ndarray, rng: np.random.Generator, metres: float, degrees: float):
    """T moved by ``metres`` and turned by ``degrees`` about a random axis through the camera."""
    d = rng.normal(size=3)
    out = T.copy()
    out[:3, :3] = rotation(rng.normal(size=3), degrees) @ T[:3, :3]
    out[:3, 3] += metres * d / np.linalg.norm(d)
    return out


def perturbed_planar(T: np.ndarray, rng: np.random.Generator, metres: float, degrees: float):
    """T moved by ``metres`` in the ground plane and turned by ``degrees`` about the vertical
    through the camera: an odometry error of a ground platform."""
    a = rng.uniform(0, 2 * math.pi)
    out = T.copy()
    out[:3, :3] = rotation([0, 0, 1], degrees) @ T[:3, :3]
    out[:2, 3] += metres * np.array([math.cos(a), math.sin(a)])
    return out


@pytest.fixture(scope="module")
def table_map(updates):
    """The registered cloud of five of the six table-top views (true poses), and the sixth."""
    frames = [m for kind, m in updates if kind == "frame"]
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL))  # fmt: skip
    memory = SceneMemory(config)
    for f in frames[:5]:
        memory.integrate(f)
    return memory.cloud.astype(np.float64), frames[5]


@pytest.mark.parametrize("dof", ["planar", "full"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_icp_recovers_a_5_cm_3_degree_odometry_error(table_map, seed, dof):
    """planar: 5 cm in the ground plane and 3° of yaw; full: 5 cm and 3° about any axis."""
    cloud, frame = table_map
    T_true = np.asarray(frame.T_world_camera)
    move = perturbed_planar if dof == "planar" else perturbed
    T_prior = move(T_true, np.random.default_rng(seed), 0.05, 3.0)
    assert pose_difference(T_true, T_prior) == pytest.approx((0.05, 3.0), abs=1e-6)
    pts = camera_points(frame.depth, frame.intrinsics, 0.35, 3.0)
    result = register(pts, T_prior, cloud, RegistrationConfig(dof=dof))
    assert result.accepted, result
    moved, turned = pose_difference(T_true, result.T_world_camera)
    assert moved <= 0.005 and turned <= 0.3, (moved, turned, result)
    assert np.allclose(result.correction @ T_prior, result.T_world_camera)


def test_registration_is_refused_where_the_geometry_does_not_constrain_it():
    """A camera 1.5 m in front of a blank wall, its map the same wall: the point-to-plane fit is
    perfect and meaningless (the frame may slide along the wall); the prior is kept."""
    K = CameraIntrinsics(width=160, height=120, fx=140.0, fy=140.0, cx=79.5, cy=59.5)
    depth = np.full((120, 160), 1.5, np.float32)
    T_true = np.eye(4)
    pts = camera_points(depth, K, 0.35, 3.0, stride=1)
    wall = pts @ T_true[:3, :3].T + T_true[:3, 3]
    T_prior = T_true.copy()
    T_prior[:3, 3] += (0.04, -0.03, 0.0)  # slid along the wall
    result = register(pts, T_prior, wall, RegistrationConfig(dof="full"))
    assert not result.accepted and result.reason == "degenerate", result
    assert np.array_equal(result.T_world_camera, T_prior)
    assert result.conditioning < 1e-3 and result.fitness > 0.9


def test_registration_is_refused_without_a_map_there(table_map):
    _, frame = table_map
    pts = camera_points(frame.depth, frame.intrinsics, 0.35, 3.0)
    far = np.random.default_rng(0).uniform(10, 11, (5000, 3))
    result = register(pts, np.asarray(frame.T_world_camera), far)
    assert not result.accepted and result.reason == "no_map_here"


def drift(i: int, metres_per_view: float, degrees_per_view: float) -> np.ndarray:
    """The odometry's error at view i (the first exact), growing by a step each view, as the
    platform's drift would: a shift in the ground plane and a turn about the vertical through
    the world's origin."""
    D = np.eye(4)
    D[:3, :3] = rotation([0, 0, 1], degrees_per_view * i)
    D[:3, 3] = (metres_per_view * i, -0.5 * metres_per_view * i, 0.0)
    return D


def drifted(frames, metres_per_view: float, degrees_per_view: float):
    """The frames as the drifting odometry places them."""
    out = []
    for i, f in enumerate(frames):
        T = drift(i, metres_per_view, degrees_per_view) @ np.asarray(f.T_world_camera)
        out.append(f.model_copy(update={"T_world_camera": T}))
    return out


@pytest.mark.parametrize("registration", [True, False])
def test_the_memory_registers_drifting_views(updates, registration):
    """Six views whose odometry drifts 1.2 cm and 0.6° more each view (6 cm and 3° by the
    last): with registration every view lands within 5 mm and 0.3° of its true pose and the
    map's cloud stays sharp; without, the last view is 5 cm off."""
    frames = [m for kind, m in updates if kind == "frame"]
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig() if registration else None)  # fmt: skip
    memory = SceneMemory(config)
    errors = []
    for true, odo in zip(frames, drifted(frames, 0.012, 0.6), strict=True):
        memory.integrate(odo)
        correction = memory.T_world_odom if memory.T_world_odom is not None else np.eye(4)
        errors.append(pose_difference(np.asarray(true.T_world_camera),
                                      correction @ np.asarray(odo.T_world_camera)))  # fmt: skip
    moved = max(e[0] for e in errors)
    turned = max(e[1] for e in errors)
    if registration:
        assert moved <= 0.005 and turned <= 0.3, errors
        assert memory.registrations_refused == 0 and memory.last_registration["accepted"]
        assert memory.timings_ms["registration_ms"] > 0
    else:
        assert moved > 0.05 and turned > 2.9, errors


def test_the_service_publishes_its_pose_corrections(client, router, procs, tmp_path, updates):
    """scene_memory --registration over Zenoh: drifting frames 0.2 s apart in, one
    PoseCorrection per integrated frame out; registration at most every 0.5 s (the default):
    a registered frame's maps its odometry pose to within 5 mm and 0.3° of its true pose, the
    frames in between say ``not_due`` and carry the last correction."""
    keys = Keys()
    got: list[PoseCorrection] = []
    client.declare_subscriber(
        keys.pose_correction(), lambda s: got.append(decode(s.payload.to_bytes(), PoseCorrection))
    )
    procs.python(
        ["-m", "services.scene_memory", "--instance", "reg", "--data-dir", str(tmp_path),
         "--voxel", str(VOXEL), "--registration", "--keyframe-move", "0",
         f"--bounds-min={','.join(map(str, BOUNDS_MIN))}",
         f"--bounds-max={','.join(map(str, BOUNDS_MAX))}"],
        env=avs_env(router),
    )  # fmt: skip
    frames = [m for kind, m in updates if kind == "frame"]
    # captured 0.2 s apart: with the service's default interval (0.5 s) frames 1 and 4 are
    # registered, 2, 3 and 5 take the last correction
    odometry = [f.model_copy(update={"stamp": 0.2 * i})
                for i, f in enumerate(drifted(frames, 0.012, 0.6))]  # fmt: skip
    pub = matched_publisher(client, keys.rgbd("head_rgbd"), timeout=60)
    for i, f in enumerate(odometry):
        pub.put(encode(f))
        wait_for(lambda i=i: len(got) == i + 1, 60, f"the correction of frame {i}")
    assert [c.frame_seq for c in got] == [f.seq for f in frames]
    assert [c.reason for c in got] == ["", "", NOT_DUE, NOT_DUE, "", NOT_DUE]
    assert [c.accepted for c in got] == [True, True, False, False, True, False]
    assert got[-1].refused == 0 and got[-1].registration_ms == 0
    assert 0 < got[4].registration_ms < 5000 and got[4].fitness > 0.4
    for i in (4, 5):  # the registered frame, and the next one placed by its correction
        T_true = np.asarray(frames[i].T_world_camera)
        moved, turned = pose_difference(T_true, got[i].T_world_odom @ odometry[i].T_world_camera)
        D = np.linalg.inv(drift(4, 0.012, 0.6)) @ drift(i, 0.012, 0.6)  # the drift since 4
        expected = pose_difference(T_true, D @ T_true)
        assert abs(moved - expected[0]) <= 0.005 and abs(turned - expected[1]) <= 0.3, (i, moved)


@pytest.mark.parametrize("registration", [True, False])
def test_fused_primitives_land_where_the_true_poses_put_them(updates, registration):
    """Frames and their observations as perception made them from the drifting odometry pose:
    with registration every fused primitive's centre falls within 5 mm of one of the
    drift-free run's; without, centimetres off."""
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig() if registration else None)  # fmt: skip
    memory = SceneMemory(config)
    i = -1
    for kind, message in updates:
        if kind == "frame":
            i += 1
            memory.integrate(
                drifted([message], 0, 0)[0].model_copy(
                    update={
                        "T_world_camera": drift(i, 0.012, 0.6) @ np.asarray(message.T_world_camera)
                    }
                )
            )
        else:
            memory.fuse(moved(message, drift(i, 0.012, 0.6)))
    truth = reference(updates).scene()
    centres = np.array([p.obb.center for p in memory.scene().primitives])
    offsets = [np.linalg.norm(centres - p.obb.center, axis=1).min() for p in truth.primitives]
    if registration:  # measured: mean 0.6 mm, largest 2.2 mm
        assert max(offsets) < 0.005, offsets
    else:  # measured: mean 21 mm, largest 82 mm
        assert np.mean(offsets) > 0.01 and max(offsets) > 0.05, offsets


def test_a_moved_observation_keeps_its_geometry_consistent(updates):
    """Every model still fits its own (moved) inliers as well as before, and the boxes and the
    camera moved with them."""
    obs = next(m for kind, m in updates if kind == "observation")
    T = drift(3, 0.05, 4.0)
    out = moved(obs, T)
    for before, after in zip(obs.primitives, out.primitives, strict=True):
        d0 = np.abs(before.model.distance(np.asarray(before.inliers, float))).mean()
        d1 = np.abs(after.model.distance(np.asarray(after.inliers, float))).mean()
        assert d1 == pytest.approx(d0, abs=1e-5)
        assert np.allclose(after.obb.center, T[:3, :3] @ before.obb.center + T[:3, 3])
    assert np.allclose(out.T_world_camera, T @ obs.T_world_camera)


def test_the_registration_map_survives_a_snapshot(updates):
    """A memory that registered five views, dumped and loaded as a snapshot is: the restored
    map holds the same voxel sums (its planes, a cache, are refitted) and registers the sixth
    view to the same pose."""
    from services.scene_memory import state as state_file

    frames = [m for kind, m in updates if kind == "frame"]
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig())  # fmt: skip
    memory = SceneMemory(config)
    for f in frames[:5]:
        memory.integrate(f)
    restored, _ = state_file.load(state_file.dump(memory, 5))
    for a, b in zip(memory.registration_map.levels, restored.registration_map.levels, strict=True):
        assert len(a) == len(b) > 0
        assert np.array_equal(a.stats[: len(a)], b.stats[: len(b)])
    T_true = np.asarray(frames[5].T_world_camera)
    T_prior = perturbed_planar(T_true, np.random.default_rng(7), 0.05, 3.0)
    pts = camera_points(frames[5].depth, frames[5].intrinsics, 0.35, 3.0)
    poses = [register(pts, T_prior, m.registration_map).T_world_camera for m in (memory, restored)]
    for T in poses:
        moved, turned = pose_difference(T_true, T)
        assert moved <= 0.005 and turned <= 0.3, (moved, turned)
    assert pose_difference(*poses)[0] < 0.001


def test_registration_runs_at_most_every_interval(updates):
    """Frames 0.2 s apart, registration at most every 0.5 s: frames 1 and 4 are registered
    (within 5 mm and 0.3°); 2, 3 and 5 are placed by the last correction, so off by the drift
    since (one or two views' 1.2 cm and 0.6°), counted as not due, and not added to the
    registration map. A stamp before the last registered one (a reset sim) registers again."""
    frames = [m for kind, m in updates if kind == "frame"]
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig(), registration_interval=0.5)  # fmt: skip
    memory = SceneMemory(config)
    odometry = [f.model_copy(update={"stamp": 0.2 * i})
                for i, f in enumerate(drifted(frames, 0.012, 0.6))]  # fmt: skip
    reasons, errors, levels = [], [], []
    for true, odo in zip(frames, odometry, strict=True):
        before = [len(v) for v in memory.registration_map.levels] if memory.cloud.size else None
        memory.integrate(odo)
        reasons.append((memory.last_registration or {}).get("reason"))
        levels.append(before == [len(v) for v in memory._registration_map().levels])
        correction = memory.T_world_odom if memory.T_world_odom is not None else np.eye(4)
        errors.append(pose_difference(np.asarray(true.T_world_camera),
                                      correction @ np.asarray(odo.T_world_camera)))  # fmt: skip
    assert reasons == [None, "", NOT_DUE, NOT_DUE, "", NOT_DUE]
    assert memory.registrations_not_due == 3 and memory.registrations_refused == 0
    assert levels == [False, False, True, True, False, True]  # carried frames add nothing
    for i, j in enumerate([0, 1, 1, 1, 4, 4]):  # each frame's last registered one
        # off by the drift since frame j: the correction is j's, D_j⁻¹
        T_true = np.asarray(frames[i].T_world_camera)
        D = np.linalg.inv(drift(j, 0.012, 0.6)) @ drift(i, 0.012, 0.6)
        expected = pose_difference(T_true, D @ T_true)
        assert abs(errors[i][0] - expected[0]) <= 0.005, (i, errors[i], expected)
        assert abs(errors[i][1] - expected[1]) <= 0.3, (i, errors[i], expected)
        assert (expected[0] > 0.01) == (i != j)
    back = odometry[5].model_copy(update={"stamp": 0.1})
    memory.integrate(back)
    assert memory.last_registration["reason"] == "" and memory.last_registration["accepted"]


def test_a_refused_frame_is_not_what_the_next_one_registers_to(updates):
    """A frame whose odometry is 0.4 m off cannot be registered: it keeps its prior and is
    fused there, but the registration map does not take its misplaced copy of the table, so
    the next frame still registers to the true one."""
    frames = [m for kind, m in updates if kind == "frame"]
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig())  # fmt: skip
    memory = SceneMemory(config)
    memory.integrate(frames[0])
    before = [len(level) for level in memory.registration_map.levels]
    cloud = len(memory.cloud)
    far = drift(1, 0.4, 0.0) @ np.asarray(frames[1].T_world_camera)
    memory.integrate(frames[1].model_copy(update={"T_world_camera": far}))
    assert not memory.last_registration["accepted"] and memory.registrations_refused == 1
    assert [len(level) for level in memory.registration_map.levels] == before
    assert len(memory.cloud) > cloud  # still fused, where odometry put it
    T_true = np.asarray(frames[2].T_world_camera)
    memory.integrate(frames[2].model_copy(update={"T_world_camera": drift(1, 0.02, 1.0) @ T_true}))
    assert memory.last_registration["accepted"], memory.last_registration
    T = memory.T_world_odom @ drift(1, 0.02, 1.0) @ T_true
    moved, turned = pose_difference(T_true, T)
    assert moved <= 0.005 and turned <= 0.3, (moved, turned)


@pytest.mark.parametrize("weighed", [True, False])
def test_a_registration_the_odometry_cannot_explain_is_refused_where_it_is_weighed(
    updates, weighed
):
    """The six views' frames twice: the first pass maps them at their true poses; then the
    first view again with its odometry pose 9 cm off, as if the platform had been carried
    without its wheels turning. ICP finds the offset (within ``max_correction_m``); weighed
    against a 2 % odometry that has not moved since the last frame (σ ≈ 0), no registration
    error (σ 2 cm) explains 9 cm (d² ≈ 20 > 16.3): refused, the correction kept. Taken as it
    comes, it is accepted."""
    frames = [m for kind, m in updates if kind == "frame"]
    odometry = OdometryNoise.share(0.02) if weighed else None
    config = MemoryConfig(bounds_min=tuple(BOUNDS_MIN), bounds_max=tuple(BOUNDS_MAX),
                          occupancy=OccupancyConfig(voxel=VOXEL),
                          registration=RegistrationConfig(odometry_noise=odometry))  # fmt: skip
    memory = SceneMemory(config)
    for f in frames:
        memory.integrate(f)
    assert memory.registrations_refused == 0
    last = frames[-1]
    memory.integrate(last)  # the filter's last pose: no motion since
    carried = last.model_copy(update={"T_world_camera": drift(1, 0.08, 0.0) @ last.T_world_camera})
    before = memory.T_world_odom.copy()
    memory.integrate(carried)
    if weighed:
        assert memory.last_registration["reason"] == INCONSISTENT
        assert memory.last_registration["mahalanobis"] > 16.27
        assert np.allclose(memory.T_world_odom, before)
    else:
        assert memory.last_registration["accepted"], memory.last_registration
        T = memory.T_world_odom @ carried.T_world_camera
        assert pose_difference(np.asarray(last.T_world_camera), T)[0] < 0.005
