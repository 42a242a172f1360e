"""The RealSense adapter on real librealsense objects without a camera: the test makes a
recording with pyrealsense2's own software device and recorder (depth, colour, gyro, accel,
with a depth-to-colour extrinsic of a real module's size), and the adapter plays it back
through rs.pipeline and rs.align, as it would stream a D435i."""

from __future__ import annotations

import platform
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from schemas import ImuSample, RgbdFrame
from schemas.codec import decode
from schemas.keys import Keys
from services.adapters.realsense import core
from services.adapters.realsense.config import RealsenseSettings
from services.adapters.realsense.device import RealsenseError, resolvable_config, stream_facts
from tests.conftest import avs_env, wait_for

if platform.machine() in ("x86_64", "AMD64"):  # scripts/setup.sh installs avs[realsense]
    import pyrealsense2 as rs
else:  # PyPI has no pyrealsense2 for this machine
    rs = pytest.importorskip("pyrealsense2")

W, H = 640, 480
FPS = 30  # the streams' nominal rate
PERIOD = 0.1  # s between recorded frames: slow enough for a loaded CI machine to keep all
FRAMES = 10
GYRO_PER_FRAME = 6  # gyro readings per frame, and half as many accel ones
DEPTH_UNITS = 1e-4  # not the usual 1 mm: the adapter must use the device's scale
# a D435i-like pair: a wide depth imager and a narrower colour camera 15 mm beside it
DEPTH_K = dict(fx=385.0, fy=385.0, ppx=320.5, ppy=238.7)
COLOUR_K = dict(fx=615.2, fy=615.9, ppx=322.1, ppy=241.3)
# a rotation that differs from its transpose, so a row/column-major mix-up shows
R_COLOUR_DEPTH = Rotation.from_euler("xyz", [0.7, 1.4, 0.5], degrees=True).as_matrix()
T_COLOUR_DEPTH = np.eye(4)
T_COLOUR_DEPTH[:3, :3], T_COLOUR_DEPTH[:3, 3] = R_COLOUR_DEPTH, (0.015, 0.0003, -0.0002)
# the scene in depth pixels: a wall, a near square, a patch beyond depth_max, a hole
NEAR = (slice(220, 260), slice(300, 340))  # rows, columns
FAR = (slice(300, 330), slice(200, 230))
HOLE = (slice(150, 170), slice(400, 440))
NEAR_M, FAR_M = 0.8, 3.6
# the camera's pose as the test configures it
POSE = dict(x=0.5, y=-0.2, z=1.1, yaw=15.0, pitch=20.0, roll=0.0)


def wall_m(k: int) -> float:
    return 1.5 + 0.01 * k


def depth_image(k: int) -> np.ndarray:
    z = np.full((H, W), wall_m(k), float)
    z[NEAR], z[FAR], z[HOLE] = NEAR_M, FAR_M, 0.0
    return np.round(z / DEPTH_UNITS).astype(np.uint16)


def colour_image(k: int) -> np.ndarray:
    return np.random.default_rng(k).integers(0, 256, (H, W, 3), dtype=np.uint8)


def gyro_reading(j: int) -> tuple[float, float, float]:
    return (0.01 * j, -0.02 * j, 0.5)


def accel_reading(i: int) -> np.ndarray:
    """Gravity in the IMU's (the depth imager's) axes for the configured pose, plus a mark."""
    R_world_colour = core.T_world_camera(0, 0, 0, POSE["yaw"], POSE["pitch"])[:3, :3]
    g = (R_world_colour @ R_COLOUR_DEPTH).T @ np.array([0, 0, core.GRAVITY])
    return (g + np.array([0.001 * i, 0, 0])).astype(np.float32)


def _intrinsics(k: dict) -> rs.intrinsics:
    i = rs.intrinsics()
    i.width, i.height, i.fx, i.fy, i.ppx, i.ppy = W, H, k["fx"], k["fy"], k["ppx"], k["ppy"]
    i.model, i.coeffs = rs.distortion.brown_conrady, [0.0] * 5
    return i


def _extrinsics(T: np.ndarray) -> rs.extrinsics:
    e = rs.extrinsics()
    e.rotation = T[:3, :3].T.ravel().tolist()  # column-major
    e.translation = T[:3, 3].tolist()
    return e


@dataclass
class Recording:
    path: Path
    gyro_ms: list[float]  # timestamp of gyro reading j
    accel_ms: list[float]


def write_recording(path: Path) -> Recording:
    """FRAMES depth + colour frames at FPS, gyro and accel readings between them, paced in
    real time (the recorder stamps messages with their arrival), into a RealSense recording."""
    dev = rs.software_device()
    dev.register_info(rs.camera_info.name, "Intel RealSense D435I (software)")
    dev.register_info(rs.camera_info.serial_number, "000000000001")
    depth_s, colour_s = dev.add_sensor("Stereo Module"), dev.add_sensor("RGB Camera")
    motion_s = dev.add_sensor("Motion Module")

    def video(kind, uid, fmt, bpp, k):
        v = rs.video_stream()
        v.type, v.index, v.uid, v.width, v.height, v.fps = kind, 0, uid, W, H, FPS
        v.bpp, v.fmt, v.intrinsics = bpp, fmt, _intrinsics(k)
        return v

    def motion(kind, uid, fps):
        m = rs.motion_stream()
        m.type, m.index, m.uid, m.fps, m.fmt = kind, 0, uid, fps, rs.format.motion_xyz32f
        mi = rs.motion_device_intrinsic()
        mi.data, mi.noise_variances, mi.bias_variances = np.eye(3, 4).tolist(), [0] * 3, [0] * 3
        m.intrinsics = mi
        return motion_s.add_motion_stream(m)

    dprof = depth_s.add_video_stream(video(rs.stream.depth, 0, rs.format.z16, 2, DEPTH_K))
    cprof = colour_s.add_video_stream(video(rs.stream.color, 1, rs.format.rgb8, 3, COLOUR_K))
    gprof, aprof = motion(rs.stream.gyro, 2, 200), motion(rs.stream.accel, 3, 100)  # nominal
    depth_s.add_read_only_option(rs.option.depth_units, DEPTH_UNITS)
    dprof.register_extrinsics_to(cprof, _extrinsics(T_COLOUR_DEPTH))
    for p in (gprof, aprof):  # the IMU's axes are the depth imager's
        p.register_extrinsics_to(dprof, _extrinsics(np.eye(4)))

    recorder = rs.recorder(str(path), dev)
    depth_s.open(dprof)
    colour_s.open(cprof)
    motion_s.open([gprof, aprof])
    for s in (depth_s, colour_s, motion_s):
        s.start(lambda _f: None)
    gyro_ms: list[float] = []
    accel_ms: list[float] = []
    start = time.monotonic()
    for tick in range(FRAMES * GYRO_PER_FRAME):
        t = tick * 1000.0 * PERIOD / GYRO_PER_FRAME
        if tick % GYRO_PER_FRAME == 0:
            k = tick // GYRO_PER_FRAME
            _video_frame(depth_s, dprof, k, depth_image(k), 2, t, DEPTH_UNITS)
            _video_frame(colour_s, cprof, k, colour_image(k), 3, t)
        if tick % 2 == 0:
            _motion_frame(motion_s, aprof, len(accel_ms), accel_reading(len(accel_ms)), t)
            accel_ms.append(t)
        _motion_frame(motion_s, gprof, len(gyro_ms), gyro_reading(len(gyro_ms)), t)
        gyro_ms.append(t)
        time.sleep(max(0.0, start + (tick + 1) * PERIOD / GYRO_PER_FRAME - time.monotonic()))
    for s in (depth_s, colour_s, motion_s):
        s.stop()
        s.close()
    del recorder  # closes the file
    return Recording(path, gyro_ms, accel_ms)


def _video_frame(sensor, profile, n, pixels, bpp, t_ms, units=None) -> None:
    f = rs.software_video_frame()
    f.pixels, f.bpp, f.stride = pixels, bpp, bpp * W
    f.timestamp, f.domain, f.frame_number = t_ms, rs.timestamp_domain.hardware_clock, n
    f.profile = profile.as_video_stream_profile()
    if units is not None:
        f.depth_units = units
    sensor.on_video_frame(f)


def _motion_frame(sensor, profile, n, xyz, t_ms) -> None:
    v = rs.vector()
    v.x, v.y, v.z = (float(c) for c in xyz)
    f = rs.software_motion_frame()
    f.data, f.timestamp, f.domain, f.frame_number = v, t_ms, rs.timestamp_domain.hardware_clock, n
    f.profile = profile.as_motion_stream_profile()
    sensor.on_motion_frame(f)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Recording:
    return write_recording(tmp_path_factory.mktemp("realsense") / "d435i.db3")


# -- the expected aligned image, from the pinhole model (not from librealsense) --------------


def project_to_colour(u: float, v: float, z: float) -> tuple[float, float]:
    """Where the depth pixel (u, v) at z metres lands in the colour image."""
    p = np.array(
        [(u - DEPTH_K["ppx"]) / DEPTH_K["fx"] * z, (v - DEPTH_K["ppy"]) / DEPTH_K["fy"] * z, z, 1]
    )
    q = T_COLOUR_DEPTH @ p
    u = COLOUR_K["fx"] * q[0] / q[2] + COLOUR_K["ppx"]
    return u, COLOUR_K["fy"] * q[1] / q[2] + COLOUR_K["ppy"]


def centre(region: tuple[slice, slice]) -> tuple[float, float]:
    rows, cols = region
    return (cols.start + cols.stop - 1) / 2, (rows.start + rows.stop - 1) / 2


def check_frame(frame: RgbdFrame, settings: RealsenseSettings) -> int:
    """Assert that ``frame`` is recorded frame k, converted and aligned; returns k."""
    k = round(frame.stamp / PERIOD)
    assert frame.stamp == pytest.approx(k * PERIOD, abs=1e-6)
    assert 0 <= k < FRAMES
    K = frame.intrinsics  # the colour stream's, which the aligned depth shares
    assert (K.width, K.height, K.fx, K.fy, K.cx, K.cy) == pytest.approx(
        (W, H, COLOUR_K["fx"], COLOUR_K["fy"], COLOUR_K["ppx"], COLOUR_K["ppy"])
    )
    np.testing.assert_array_equal(frame.rgb, colour_image(k))
    np.testing.assert_allclose(
        frame.T_world_camera,
        core.T_world_camera(POSE["x"], POSE["y"], POSE["z"], POSE["yaw"], POSE["pitch"]),
    )
    assert (frame.depth_min, frame.depth_max) == (settings.depth_min, settings.depth_max)
    depth = frame.depth
    assert depth.dtype == np.float32 and depth.shape == (H, W)
    # the wall: every covered pixel in metres by the device's scale
    u, v = project_to_colour(250, 200, wall_m(k))
    assert depth[round(v), round(u)] == pytest.approx(wall_m(k), abs=1e-6)
    values = np.unique(depth)  # only what the scene holds: no interpolated depths
    allowed = np.array([0.0, NEAR_M, wall_m(k)])
    assert np.abs(values[:, None] - allowed).min(axis=1).max() < 1e-5, values
    # the near square, moved and magnified where the extrinsics and intrinsics put it
    rows, cols = np.nonzero(np.abs(depth - NEAR_M) < 1e-4)
    u, v = project_to_colour(*centre(NEAR), NEAR_M)
    assert cols.mean() == pytest.approx(u, abs=0.75) and rows.mean() == pytest.approx(v, abs=0.75)
    scale = COLOUR_K["fx"] / DEPTH_K["fx"]
    assert len(rows) == pytest.approx(40 * 40 * scale**2, rel=0.1)
    # beyond depth_max and the hole: no return (0), not NaN
    for region, z in ((FAR, FAR_M), (HOLE, wall_m(k))):
        u, v = project_to_colour(*centre(region), z)
        assert depth[round(v), round(u)] == 0.0
    return k


# -- tests --------------------------------------------------------------------------------------


def test_stream_facts_of_a_recording(recording: Recording) -> None:
    """What the adapter asks for resolves against the recording, and what it reads back."""

    def settings(**fields) -> RealsenseSettings:
        return RealsenseSettings(playback=recording.path, **fields)

    pipeline = rs.pipeline()
    config, imu = resolvable_config(rs, pipeline, settings())
    assert imu
    assert resolvable_config(rs, rs.pipeline(), settings(imu=False))[1] is False
    profile = pipeline.start(config)
    try:
        facts = stream_facts(rs, profile, imu=True)
    finally:
        pipeline.stop()
    assert facts.depth_scale == pytest.approx(DEPTH_UNITS)
    assert facts.colour_format == "format.rgb8"
    assert facts.serial == "000000000001"
    K = facts.intrinsics  # the colour stream's
    assert (K.fx, K.fy, K.cx, K.cy) == pytest.approx(
        [COLOUR_K[k] for k in ("fx", "fy", "ppx", "ppy")]
    )
    assert not facts.distorted
    np.testing.assert_allclose(facts.R_colour_imu, R_COLOUR_DEPTH, atol=1e-6)
    with pytest.raises(RealsenseError, match="1280"):
        resolvable_config(rs, rs.pipeline(), settings(width=1280, height=720))


@pytest.fixture
def streams(client: zenoh.Session) -> Iterator[tuple[list[RgbdFrame], list[ImuSample]]]:
    keys = Keys()
    frames: list[RgbdFrame] = []
    imu: list[ImuSample] = []
    lock = threading.Lock()

    def on(kind: type, into: list):
        def handler(sample: zenoh.Sample) -> None:
            with lock:
                into.append(decode(sample.payload.to_bytes(), kind))

        return handler

    subs = [
        client.declare_subscriber(keys.rgbd("head_rgbd"), on(RgbdFrame, frames)),
        client.declare_subscriber(keys.imu(), on(ImuSample, imu)),
    ]
    yield frames, imu
    for s in subs:
        s.undeclare()


@pytest.mark.slow
def test_adapter_plays_a_recording_onto_the_sim_keys(
    recording: Recording, router: str, streams, procs
) -> None:
    """``python -m services.adapters.realsense --playback``: frames in, RgbdFrames and
    ImuSamples out over Zenoh, every value checked against what was recorded."""
    frames, imu = streams
    pose = [f"--{name}={value}" for name, value in POSE.items()]
    p = procs.python(
        ["-m", "services.adapters.realsense", "--playback", str(recording.path), *pose,
         "--playback-linger", "0.5"],
        env=avs_env(router),
    )  # fmt: skip
    wait_for(lambda: p.poll() is not None, 60, "the playback to end")
    assert p.returncode == 0
    settings = RealsenseSettings(playback=recording.path, **POSE)
    seen = [check_frame(f, settings) for f in frames]
    assert len(seen) >= FRAMES // 2, f"only frames {seen} of {FRAMES} came"
    assert seen == sorted(seen) and [f.seq for f in frames] == list(range(len(frames)))

    assert len(imu) >= len(recording.gyro_ms) // 2, f"{len(imu)} IMU samples"
    R_world_imu = core.T_world_camera(0, 0, 0, POSE["yaw"], POSE["pitch"])[:3, :3] @ R_COLOUR_DEPTH
    accels = np.array([accel_reading(i) for i in range(len(recording.accel_ms))], float)
    gyros = np.array([gyro_reading(j) for j in range(len(recording.gyro_ms))], float)
    last_accel = 0
    for n, sample in enumerate(imu):
        assert sample.seq == n and sample.frame == "head_imu"
        j = int(np.argmin(np.abs(sample.angular_velocity - gyros).sum(axis=1)))
        np.testing.assert_allclose(sample.angular_velocity, gyro_reading(j), atol=1e-6)
        assert sample.stamp == pytest.approx(recording.gyro_ms[j] / 1e3)
        i = int(np.argmin(np.abs(sample.linear_acceleration - accels).sum(axis=1)))
        np.testing.assert_allclose(sample.linear_acceleration, accels[i], atol=1e-6)
        # the newest accel reading the adapter had: never an older one than before, and
        # recent (playback delivers gyro and accel on threads of their own, and may drop)
        assert i >= last_accel
        last_accel = i
        assert abs(recording.accel_ms[i] - recording.gyro_ms[j]) <= 3e3 * PERIOD
        np.testing.assert_allclose(sample.orientation, core.quaternion(R_world_imu), atol=1e-6)
        # gravity, rotated into the world by the orientation, points up
        up = R_world_imu @ sample.linear_acceleration
        np.testing.assert_allclose(up, [0, 0, core.GRAVITY], atol=0.05)
