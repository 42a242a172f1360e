"""The object-localisation-while-moving experiment (thesis 5.4.1, Table 5.1, Fig. 5.9/5.10):
ARMAR-III fixates an object 1.5 m ahead with its foveal cameras while the hip swings
(q̇ = A·cos(2πft), Eq. 5.5), with the gaze stabiliser on or off.

The sim runs in lockstep at 1 kHz with the stabiliser's control step between physics steps
(the same core the gaze service runs). The left foveal camera is rendered at 30 Hz; each frame
integrates light over an exposure (the mean of renders across it), so a camera that moves
during the exposure gives a blurred image, as a real one does. Per frame: the optical-flow
error against the previous frame, the perceptual blur, and whether the object is localised;
once for the cup (HSV segmentation), once for the textured box (feature matching).

``exposure_mode`` is the camera's exposure (Fig. 5.9b, ``services/sim/exposure.py``): "fixed"
keeps the gain of the still view, "auto" runs the camera's auto-exposure loop, which follows
the brighter and darker views of a swing a frame late and with a time constant, so frames come
over- or under-exposed. Both start from the same still frame (the loop settled on it), so the
finders are the same in both modes.

With ``sensors`` (the default) the controller sees what the live stack gives it: the robot's
gyro with white noise and a drifting bias, joint states from noisy 14-bit encoders at 200 Hz,
each 2 ms late (``services/sim/sensors.py``), the gyro sample of each joint state's instant
for the VOR, as the gaze node takes it, and the platform where the odometry believes it is (the
target is given in world coordinates, which the robot relates to itself through that belief);
without, the simulator's exact state every step. The gaze error is always the true camera's."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from experiments.image_quality import CupFinder, TextureFinder, blur, flow_rmse_deg_s
from services.common.robots import robot_mjcf
from services.gaze.config import FIXATING
from services.gaze.kinematics import HEAD_JOINTS, GazeKinematics
from services.gaze.sensing import nearest
from services.gaze.stabiliser import GazeStabiliser, StabiliserConfig
from services.sim.exposure import Exposure, mean_luma
from services.sim.render import CameraRenderer, intrinsics
from services.sim.robots import ROBOTS
from services.sim.sensors import RobotSensors
from services.sim.world import World

#: the objects of the localization scene, and how each is found
OBJECTS = {"cup": "cup", "textured": "textured_box"}


@dataclass
class GazeExperimentConfig:
    robot: str = "armar3"
    scene: str = "localization"
    disturbance: str = "hip_yaw"
    amplitude: float = 20.0  # deg/s
    frequency: float = 0.25  # Hz
    duration: float = 10.0  # s
    stabilize: bool = True
    camera: str = "left_foveal"
    fps: float = 30.0
    exposure: float = 0.02  # s of light per frame (integration time: the blur)
    exposure_mode: str = "fixed"  # the gain: "fixed", or "auto" (the camera's AE loop)
    ae_tau: float = 0.4  # s, the AE loop's time constant
    subframes: int = 4  # renders averaged over the exposure
    settle: float = 1.0  # s of fixating before the disturbance starts
    sensors: bool = True  # the robot's sensor models (noise, bias, latency), else exact state
    #: how far off the truth the odometry believes the platform at the start (x m, y m,
    #: yaw rad), as after a drive (with ``sensors``); the platform stands, so it stays off
    odometry_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
    state_rate: float = 200.0  # joint states per second with the sensor models (the sim's)
    seed: int = 0


#: frame pairs whose flow may be pending at once (each pair holds two 3.7 MB frames)
FLOWS_AHEAD = 8


@dataclass
class ObjectRun:
    times: list[float]
    flow: list[float]  # deg/s, per frame pair
    blur: list[float]
    found: list[bool]
    error_deg: list[float]  # the true gaze error at each frame
    brightness: list[float]  # the frame's mean luma, 0-255
    gain: list[float]  # the exposure gain of the frame (1: the still view's)


def _corners(model, data, body: str) -> np.ndarray:
    """World corners of the boxes of a body's geoms (its bounding points)."""
    b = model.body(body).id
    pts = []
    for g in range(model.ngeom):
        if model.geom_bodyid[g] != b:
            continue
        R, p, size = data.geom_xmat[g].reshape(3, 3), data.geom_xpos[g], model.geom_size[g]
        half = np.array([size[0], size[0], size[1]]) if model.geom_type[g] == 5 else size
        for s in np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T:
            pts.append(p + R @ (s * half))
    return np.array(pts)


def _project(T: np.ndarray, K, points: np.ndarray) -> np.ndarray:
    c = (np.atleast_2d(points) - T[:3, 3]) @ T[:3, :3]
    return np.column_stack([K.fx * c[:, 0] / c[:, 2] + K.cx, K.fy * c[:, 1] / c[:, 2] + K.cy])


def run_object(
    config: GazeExperimentConfig, name: str, progress: Callable[[float], None] | None = None
) -> ObjectRun:
    c = config
    if c.exposure_mode not in ("fixed", "auto"):
        raise ValueError(f"exposure_mode is 'fixed' or 'auto', not {c.exposure_mode!r}")
    robot = ROBOTS[c.robot]
    world = World(c.scene, robot)
    body = OBJECTS[name]
    target = world.data.xpos[world.model.body(body).id].copy()
    cams = FIXATING[c.robot]
    stab = GazeStabiliser(
        GazeKinematics(robot_mjcf(c.robot), cams),
        StabiliserConfig(HEAD_JOINTS[c.robot], cams, speed=robot.joint_speed),
    )
    cam_id = world.cameras[c.camera]
    renderer = CameraRenderer(world.model, 640, 480)
    K = intrinsics(world.model, cam_id, 640, 480)
    deg_per_px = (math.degrees(math.atan(1 / K.fx)), math.degrees(math.atan(1 / K.fy)))

    sensors = RobotSensors(robot.sensors, c.seed, world.base_pose()[:3]) if c.sensors else None
    if sensors is not None:
        start = np.array(world.base_pose()[:3])
        sensors.odometry.reset(tuple(start), tuple(start + c.odometry_error))
    state_every = max(1, round(1 / (c.state_rate * world.timestep)))
    gyros: deque[tuple[float, np.ndarray]] = deque(maxlen=20)
    latest: list = []  # the newest delivered joint state: (stamp, names, q, q̇)

    def sense() -> None:
        """One physics step's measurements: a gyro sample, and every ``state_every`` steps a
        joint state that arrives ``joint_latency`` later and the odometry's platform pose."""
        gyro, acc, _ = world.imu()
        gyros.append((world.time, sensors.imu.measure(gyro, acc, world.timestep)[0]))
        if world.steps % state_every == 0:
            sensors.odometry.update(world.base_pose()[:3])
            names, q, qd = world.joint_state()
            q, qd = sensors.encoders.measure(q, qd)
            sensors.joint_states.push(world.time, (world.time, names, q, qd))
        for js in sensors.joint_states.due(world.time):
            latest[:] = [js]

    def control() -> None:
        """One control step on what the robot knows: the measured joints and gyro, and the
        platform where the odometry believes it is (without ``sensors``: the truth)."""
        x, y, yaw, vx, vy, wz = world.base_pose()
        base, twist = (x, y, yaw), (vx, vy, wz)
        if sensors is None:
            names, q, qd = world.joint_state()
            gyro, latency = world.imu()[0], 0.0
        else:
            sense()
            if not latest:
                return
            t, names, q, qd = latest[0]
            gyro, latency = nearest(gyros, t, 0.6 * world.timestep), world.time - t
            base, twist = sensors.odometry.believed, sensors.base_velocity(vx, vy, wz)
        cmd = stab.command(
            target, base, twist, dict(zip(names, q, strict=True)),
            dict(zip(names, qd, strict=True)), gyro, world.time, latency,
        )  # fmt: skip
        world.command_joints(list(cmd.velocity), "velocity", np.array([*cmd.velocity.values()]))

    def render() -> np.ndarray:
        renderer.snapshot(world.data, cam_id)
        return renderer.render(depth=False)[0].astype(np.float32)

    for _ in range(int(c.settle / world.timestep)):  # fixate first, as in the thesis
        control()
        world.step()
    still = render().astype(np.uint8)
    if name == "cup":
        finder = CupFinder.from_reference(still)
    else:
        uv = _project(world.T_world_camera(c.camera), K, _corners(world.model, world.data, body))
        lo, hi = np.floor(uv.min(0)).astype(int), np.ceil(uv.max(0)).astype(int)
        finder = TextureFinder.from_reference(still, (*np.clip(lo, 0, 639), *np.clip(hi, 0, 479)))
    # the AE's target is the still view's brightness: the loop has settled on it, at gain 1
    exposure = Exposure(mean_luma(still), auto=c.exposure_mode == "auto", tau=c.ae_tau)
    world.set_disturbance(c.disturbance, math.radians(c.amplitude), c.frequency)
    t0, steps = world.time, round(c.duration / world.timestep)
    period = round(1 / (c.fps * world.timestep))
    span = round(c.exposure / world.timestep)
    fps = 1.0 / (period * world.timestep)  # the frame rate the step grid allows
    # the render steps of frame k: its exposure ends at the frame's time
    offsets = np.unique(np.round(np.linspace(-span, 0, c.subframes)).astype(int))
    run = ObjectRun([], [], [], [], [], [], [])
    light, prev = None, None
    # the optical flow of each frame pair (OpenCV's Farnebäck: 70 ms a pair, on one core,
    # the GIL let go) on a thread of its own while the simulation goes on; a few pairs ahead
    # at most, each flow in its frame's place
    flows: deque[Future] = deque()
    pool = ThreadPoolExecutor(1, thread_name_prefix="flow")
    for k in range(1, steps + 1):
        if c.stabilize:
            control()
        world.step()
        in_frame = k % period
        if in_frame == 0 or (in_frame - period) in offsets:
            img = render()
            light = img if light is None else light + img
        if in_frame == 0:
            run.gain.append(exposure.gain)
            frame = exposure.frame(light / len(offsets), 1 / fps)
            light = None
            T = world.T_world_camera(c.camera)
            where = _project(T, K, target)[0]
            run.times.append(world.time - t0)
            run.blur.append(blur(frame))
            run.brightness.append(mean_luma(frame))
            run.found.append(finder.found(frame, where))
            to, z = target - T[:3, 3], T[:3, 2]
            run.error_deg.append(math.degrees(math.atan2(np.linalg.norm(np.cross(z, to)), z @ to)))
            if prev is not None:
                flows.append(pool.submit(flow_rmse_deg_s, prev, frame, deg_per_px, fps))
                while len(flows) > FLOWS_AHEAD:
                    run.flow.append(flows.popleft().result())
            prev = frame
            if progress is not None:
                progress(k / steps)
    renderer.close()
    run.flow += [f.result() for f in flows]
    pool.shutdown()
    if progress is not None:
        progress(1.0)
    return run


def summarise(runs: dict[str, ObjectRun]) -> dict:
    """metrics.json: flow error, blur, brightness and exposure gain over every frame of both
    runs, success per object."""
    flow = np.concatenate([r.flow for r in runs.values()])
    b = np.concatenate([r.blur for r in runs.values()])
    lum = np.concatenate([r.brightness for r in runs.values()])
    gain = np.concatenate([r.gain for r in runs.values()])
    return {
        "flow_rmse_deg_s": {"mean": float(flow.mean()), "std": float(flow.std()),
                            "max": float(flow.max())},
        "blur": {"mean": float(b.mean()), "max": float(b.max())},
        "brightness": {"mean": float(lum.mean()), "min": float(lum.min()),
                       "max": float(lum.max())},
        "exposure_gain": {"min": float(gain.min()), "max": float(gain.max())},
        "localization_success": {k: float(np.mean(r.found)) for k, r in runs.items()},
        "gaze_error_deg": {k: float(np.sqrt(np.mean(np.square(r.error_deg))))
                           for k, r in runs.items()},
        "frames": {k: len(r.found) for k, r in runs.items()},
    }  # fmt: skip
