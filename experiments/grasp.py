"""The grasping-while-moving experiment (thesis 5.4.2, Table 5.1, Fig. 5.11/5.12): ARMAR-III
drives along a straight path past a table and grasps a green cup whose position it does not
know, without stopping.

Lockstep at 1 kHz, like ``experiments.gaze``. What the robot does:

- **Attention** (5.1, 5.4.2): colour blobs in the peripheral stereo pair (5 Hz) draw the gaze at
  a constant saliency; the cup's and the hand's localisation uncertainties are saliencies too,
  s = max(0, u(σ) − b(α)) (Eq. 5.2–5.4, ``ObjectBelief``). Every ``select_every`` s the most
  salient target wins (a fixated blob is inhibited for a while). The task acuity α changes
  with the task: the hand matters once the servo runs, the cup's acuity is raised once it is in
  reach, which shifts the gaze from the hand back to the cup (Fig. 5.12).
- **Localisation**: the foveal stereo pair (10 Hz, each frame integrating light over its
  exposure, so motion blurs it) segments the green cup and the red ball on the hand's wrist;
  stereo points with their covariance update Kalman filters (the hand's filter holds the
  offset between where the cameras see the marker and where the arm's kinematics put it).
- **Gaze**: with ``stabilize`` the gaze stabiliser (5.2) holds the target on the foveal axes
  every millisecond; without, the same controller makes the saccade to each new target and then
  lets go, so the platform's motion carries the gaze off it.
- **Grasp**: position-based visual servoing (``experiments.servo``) on the cup's projected,
  then real, pose; the servo's arm model is off by a small calibration error per joint, which
  the seen hand corrects.

With ``sensors`` the robot's readings come through the sensor models (gyro noise and bias,
encoder noise and latency, odometry drift).

Whether the cup was grasped is MuJoCo's to say, not the servo's: the cup lifted off the table
and held between the fingers to the end (``GraspExperimentConfig.grasp_lift`` …)."""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from experiments.grasp_vision import HUES, StereoCheck, find_blob, localise, silhouette_area
from experiments.image_quality import blur, flow_rmse_deg_s
from experiments.servo import GraspServo, ServoConfig
from services.common.arm import ArmKinematics
from services.common.robots import robot_mjcf
from services.gaze.kinematics import HEAD_JOINTS, GazeKinematics
from services.gaze.saliency import ObjectBelief
from services.gaze.sensing import nearest
from services.gaze.stabiliser import GazeStabiliser, StabiliserConfig
from services.sim.render import CameraRenderer, intrinsics
from services.sim.robots import ROBOTS
from services.sim.scene import ROBOT_PREFIX
from services.sim.sensors import RobotSensors, planar
from services.sim.world import World

FOVEAL = ("left_foveal", "right_foveal")
PERIPHERAL = ("left_peripheral", "right_peripheral")
#: the object models the localisation checks blobs against (m): the cup (r, half height), the
#: hand's marker ball (r,)
CUP = (0.033, 0.05)
MARKER = (0.022,)


@dataclass
class GraspExperimentConfig:
    robot: str = "armar3"
    scene: str = "grasping"
    arm: str = "left"
    target: str = "cup"  # the body to grasp (green)
    speed: float = 0.15  # m/s, the platform's
    #: a sway of the body while the platform drives: hip yaw q̇ = A·cos(2πft), (A deg/s, f Hz);
    #: off by default (the sim's drive is smooth: the route's turns and the translation are
    #: what moves the gaze)
    sway: tuple[float, float] = (0.0, 0.5)
    #: the planned trajectory: waypoints (x, y, yaw) from the scene's robot_start, then a goal
    route: tuple[tuple[float, float, float], ...] = ((2.0, -0.2, 0.2), (2.45, 0.0, 0.0))
    goal: tuple[float, float, float] = (4.6, 0.0, 0.0)
    duration: float = 24.0  # s at most
    #: s the run goes on once the servo is done: the cup carried while the platform drives on
    #: (what ``grasp_hold_s`` judges the grasp over)
    carry_s: float = 2.0
    stabilize: bool = True
    fps: float = 30.0  # left foveal frames per second (the optical flow's)
    localise_every: int = 3  # frames: the foveal pair localises at fps / this (10 Hz)
    peripheral_fps: float = 5.0
    exposure: float = 0.02  # s of light per foveal frame
    subframes: int = 3  # renders averaged over the exposure
    select_every: float = 0.5  # s between view selections
    saccade_s: float = 0.3  # s the controller runs for a gaze shift when not stabilising
    blob_saliency: float = 0.5
    inhibition_s: float = 3.0  # s a fixated blob is not selected again
    #: task acuities α (m): the cup while it is found, the hand while servoing, the cup in reach
    acuity_search: float = 0.01
    acuity_hand: float = 0.004
    acuity_grasp: float = 0.002
    raise_ahead: float = 0.3  # m before the reach the cup's acuity is raised
    process_noise: float = 2e-5  # m²/s added to a belief's variances while it is not seen
    sigma_px: float = 1.0  # pixel noise of a blob's centre
    kinematic_error_deg: float = 0.5  # σ of the servo's per-joint calibration error
    sensors: bool = True
    seed: int = 0
    #: what counts as grasped, judged on MuJoCo's state at the end: the cup at least
    #: ``grasp_lift`` above where it stood, and over the last ``grasp_hold_s`` never further
    #: than ``grasp_near`` from the grasp site between the fingers (m, s, m)
    grasp_lift: float = 0.05
    grasp_hold_s: float = 2.0
    grasp_near: float = 0.03


@dataclass
class GraspRun:
    times: list[float] = field(default_factory=list)  # foveal frames
    flow: list[float] = field(default_factory=list)  # deg/s, per frame pair
    blur: list[float] = field(default_factory=list)
    found: list[bool] = field(default_factory=list)  # the cup localised in the frame
    uncertainty: list[tuple[float, float]] = field(default_factory=list)  # (t, σ of the cup)
    targets: list[tuple[float, str]] = field(default_factory=list)  # view selections
    phases: list[tuple[float, str]] = field(default_factory=list)  # the servo's
    strip: list[tuple[float, np.ndarray]] = field(default_factory=list)  # foveal frames
    first_localised_s: float | None = None
    acuity_raised_s: float | None = None  # when the cup came near the reach
    acuity_reached_s: float | None = None  # when its σ first met the raised acuity after that
    #: MuJoCo's state every 10 ms, what the grasp is judged by (not the servo's phase):
    #: (t, the cup's height above where it stood, its distance to the grasp site, the fingers'
    #: closure 0 open … 1 fully closed)
    cup_track: list[tuple[float, float, float, float]] = field(default_factory=list)
    grasped: bool = False
    lift_m: float = 0.0  # the cup's height above where it stood, at the end
    hold_m: float = math.inf  # its largest distance to the grasp site over the last hold_s
    gripper_max: float = 0.0  # the fingers' largest closure


def _K(world: World, camera: str) -> tuple[np.ndarray, object]:
    k = intrinsics(world.model, world.cameras[camera], 640, 480)
    return np.array([[k.fx, 0, k.cx], [0, k.fy, k.cy], [0, 0, 1.0]]), k


class _Robot:
    """What the robot knows of itself: measured joints (through the sensor models), odometry,
    and the camera poses its kinematics give for them."""

    def __init__(self, world: World, c: GraspExperimentConfig) -> None:
        self.world, self.c = world, c
        robot = world.robot
        self.sensors = (
            RobotSensors(robot.sensors, c.seed, world.base_pose()[:3]) if c.sensors else None
        )
        self.every = max(1, round(1 / (200.0 * world.timestep)))  # 200 Hz joint states
        self.gyros: deque[tuple[float, np.ndarray]] = deque(maxlen=20)
        self.latest: tuple | None = None
        self.eyes = GazeKinematics(robot_mjcf(c.robot), [*FOVEAL, *PERIPHERAL])

    def sense(self) -> None:
        w, s = self.world, self.sensors
        if s is None:
            return
        gyro, acc, _ = w.imu()
        self.gyros.append((w.time, s.imu.measure(gyro, acc, w.timestep)[0]))
        s.odometry.update(w.base_pose()[:3])
        if w.steps % self.every == 0:
            names, q, qd = w.joint_state()
            q, qd = s.encoders.measure(q, qd)
            s.joint_states.push(w.time, (w.time, names, q, qd))
        for js in s.joint_states.due(w.time):
            self.latest = js

    def state(self):
        """(joint positions, joint velocities, odometry pose, odometry velocity, gyro, latency)."""
        w = self.world
        x, y, yaw, vx, vy, wz = w.base_pose()
        if self.sensors is None or self.latest is None:
            names, q, qd = w.joint_state()
            return (dict(zip(names, q, strict=True)), dict(zip(names, qd, strict=True)),
                    (x, y, yaw), (vx, vy, wz), w.imu()[0], 0.0)  # fmt: skip
        t, names, q, qd = self.latest
        gyro = nearest(self.gyros, t, 0.6 * w.timestep)
        return (dict(zip(names, q, strict=True)), dict(zip(names, qd, strict=True)),
                self.sensors.odometry.believed, self.sensors.base_velocity(vx, vy, wz), gyro,
                w.time - t)  # fmt: skip

    def cameras(self) -> dict[str, np.ndarray]:
        q, _, base, *_ = self.state()
        self.eyes.update(self.eyes.configuration(base, q))
        return {c: self.eyes.camera_pose(c) for c in (*FOVEAL, *PERIPHERAL)}


def run_grasp(
    config: GraspExperimentConfig, progress: Callable[[float], None] | None = None
) -> GraspRun:
    c = config
    robot = dataclasses.replace(ROBOTS[c.robot], vel_lin=c.speed)
    world = World(c.scene, robot)
    me = _Robot(world, c)
    cams = list(FOVEAL)
    stab = GazeStabiliser(
        GazeKinematics(robot_mjcf(c.robot), cams),
        StabiliserConfig(HEAD_JOINTS[c.robot], cams, speed=robot.joint_speed),
    )
    arm = ArmKinematics(c.robot, c.arm)
    rng = np.random.default_rng([c.seed, 16])
    calibration = dict(
        zip(arm.spec.joints, rng.normal(0, math.radians(c.kinematic_error_deg), 7), strict=True)
    )
    servo = GraspServo(arm, ServoConfig())
    renderer = CameraRenderer(world.model, 640, 480)
    K = {cam: _K(world, cam) for cam in (*FOVEAL, *PERIPHERAL)}
    deg_per_px = (math.degrees(math.atan(1 / K[FOVEAL[0]][1].fx)),
                  math.degrees(math.atan(1 / K[FOVEAL[0]][1].fy)))  # fmt: skip
    check = StereoCheck()
    cup_id = world.model.body(c.target).id
    cup_z0 = float(world.data.xpos[cup_id][2])
    grasp_site = world.model.site(ROBOT_PREFIX + arm.spec.grasp_site).id
    fingers = [world.servos[f] for f in arm.spec.fingers]

    world.set_base_goal(*c.goal, path=np.array(c.route) if c.route else None)
    if c.sway[0] > 0:
        world.set_disturbance("hip_yaw", math.radians(c.sway[0]), c.sway[1])

    cup: ObjectBelief | None = None
    hand: ObjectBelief | None = None  # the offset: seen marker − modelled marker (world)
    blobs: dict[str, tuple[np.ndarray, float]] = {}  # colour → (point, when seen)
    inhibited: dict[str, float] = {}
    T0 = me.cameras()[FOVEAL[0]]
    target_name, target = "ahead", T0[:3, 3] + 2.0 * T0[:3, 2]
    saccade_until = c.saccade_s
    raised = False  # the cup's acuity, once it comes near the reach
    run = GraspRun()

    def track() -> None:
        """MuJoCo's own account of the grasp, which the servo's phase is not."""
        d = world.data
        closure = float(np.mean([d.qpos[f.qpos] / f.upper for f in fingers]))
        near = float(np.linalg.norm(d.xpos[cup_id] - d.site_xpos[grasp_site]))
        run.cup_track.append((world.time, float(d.xpos[cup_id][2]) - cup_z0, near, closure))

    def model_q(q: dict[str, float]) -> dict[str, float]:
        return {n: v + calibration.get(n, 0.0) for n, v in q.items()}

    def hand_point(q: dict[str, float], base) -> np.ndarray:
        p = arm.marker(model_q(q), base)
        return p + (hand.mean if hand is not None else 0.0)

    def acuities() -> tuple[float, float]:
        return (c.acuity_grasp if raised else c.acuity_search), c.acuity_hand

    def select(now: float, q, base) -> None:
        nonlocal target_name, saccade_until
        options: list[tuple[float, str]] = []
        a_cup, a_hand = acuities()
        if cup is not None:
            cup.predict(now)
            cup.acuity = a_cup
            options.append((cup.saliency, "cup"))
        if servo.phase != "wait":
            if hand is None:  # the hand not seen yet: as uncertain as the calibration
                options.append((ObjectBelief.first(np.zeros(3), 1e-4 * np.eye(3), now, a_hand)
                                .saliency, "hand"))  # fmt: skip
            else:
                hand.predict(now)
                hand.acuity = a_hand
                options.append((hand.saliency, "hand"))
        for colour, (_, seen) in blobs.items():
            if now - seen < 1.0 and inhibited.get(colour, -1.0) < now:
                options.append((c.blob_saliency, colour))
        options = [o for o in options if o[0] > 0]
        if not options:
            return
        best = max(options)[1]
        if best != target_name:  # a gaze shift (unstabilised: the only time the head moves)
            saccade_until = now + c.saccade_s
            run.targets.append((now, best))
        if best in blobs:
            inhibited[best] = now + c.inhibition_s
        target_name = best

    def aim(q, base) -> np.ndarray:
        if target_name == "cup" and cup is not None:
            return cup.mean
        if target_name == "hand":
            return hand_point(q, base)
        if target_name in blobs:
            return blobs[target_name][0]
        return target

    def foveal_frame(frames: dict[str, np.ndarray], poses, q, base) -> None:
        nonlocal cup, hand
        now = world.time
        (KL, _), (KR, _) = K[FOVEAL[0]], K[FOVEAL[1]]
        TL, TR = poses[FOVEAL[0]], poses[FOVEAL[1]]
        bl, br = (find_blob(frames[f], "green") for f in FOVEAL)
        ok = False
        # once the hand is at the cup it hides part of it, and what is left of the blob is not
        # the cup's centre: the cup stands still, so its belief is kept as it is from then on
        occluded = servo.phase in ("grasp", "close", "lift", "done")
        if not occluded and check.accepts(bl, br):
            p, S, gap = localise(bl.centre, br.centre, KL, KR, TL, TR, c.sigma_px)
            model = tuple(
                silhouette_area("cylinder", CUP, p, T, K_) for T, K_ in ((TL, KL), (TR, KR))
            )
            if check.accepts(bl, br, gap, model):
                ok = True
                if cup is None:
                    cup = ObjectBelief.first(p, S, now, c.acuity_search)
                    cup.process_noise = c.process_noise
                    run.first_localised_s = now
                else:
                    cup.update(p, S, now)
        ml, mr = (find_blob(frames[f], "red", min_area=30) for f in FOVEAL)
        if check.accepts(ml, mr):
            p, S, gap = localise(ml.centre, mr.centre, KL, KR, TL, TR, c.sigma_px)
            model = tuple(
                silhouette_area("sphere", MARKER, p, T, K_) for T, K_ in ((TL, KL), (TR, KR))
            )
            if check.accepts(ml, mr, gap, model):
                offset = p - arm.marker(model_q(q), base)
                if hand is None:
                    hand = ObjectBelief.first(offset, S, now, c.acuity_hand)
                    hand.process_noise = c.process_noise
                else:
                    hand.update(offset, S, now)
        run.found.append(ok)
        if cup is not None:
            cup.predict(now)
            run.uncertainty.append((now, cup.sigma))
            if raised and run.acuity_reached_s is None and cup.sigma <= c.acuity_grasp:
                run.acuity_reached_s = now

    def peripheral_frame(frames: dict[str, np.ndarray], poses) -> None:
        (KL, _), (KR, _) = K[PERIPHERAL[0]], K[PERIPHERAL[1]]
        for colour in HUES:
            if colour == "red":  # the hand's own marker
                continue
            bl, br = (find_blob(frames[f], colour, min_area=20) for f in PERIPHERAL)
            if bl is None or br is None or bl.touches_border or br.touches_border:
                continue
            p, _, gap = localise(bl.centre, br.centre, KL, KR, poses[PERIPHERAL[0]],
                                 poses[PERIPHERAL[1]])  # fmt: skip
            if gap < 0.05 and (cup is None or np.linalg.norm(p - cup.mean) > 0.1):
                blobs[colour] = (p, world.time)

    def render(camera: str) -> np.ndarray:
        renderer.snapshot(world.data, world.cameras[camera])
        return renderer.render(depth=False)[0].astype(np.float32)

    period = round(1 / (c.fps * world.timestep))
    p_period = round(1 / (c.peripheral_fps * world.timestep))
    span = round(c.exposure / world.timestep)
    offsets = np.unique(np.round(np.linspace(-span, 0, c.subframes)).astype(int))
    fps = 1.0 / (period * world.timestep)
    light: dict[str, np.ndarray] = {}
    prev: np.ndarray | None = None
    steps = round(c.duration / world.timestep)
    done_at: float | None = None
    for k in range(1, steps + 1):
        me.sense()
        q, qd, base, twist, gyro, latency = me.state()
        now = world.time
        if k % 10 == 0:  # the servo and attention at 100 Hz
            if k % round(c.select_every / world.timestep) == 0:
                select(now, q, base)
            Tb = planar(*base)
            cup_base = (np.linalg.inv(Tb) @ np.array([*cup.mean, 1.0]))[:3] if cup else None
            offset = Tb[:3, :3].T @ hand.mean if hand is not None else np.zeros(3)
            rel = -(Tb[:3, :3].T @ np.array([twist[0], twist[1], 0.0]))
            if (
                not raised
                and cup_base is not None
                and (cup_base[0] < servo.config.reach[1] + c.raise_ahead)
            ):
                raised, run.acuity_raised_s = True, now
            ready = (
                cup is not None and hand is not None
                and cup.sigma <= c.acuity_grasp and hand.sigma <= c.acuity_hand
            )  # fmt: skip
            carried = arm.carried(model_q(q), qd)
            s = servo.step(now, model_q(q), offset, cup_base, rel, ready, carried)
            world.command_arm(c.arm, "velocity", list(arm.spec.joints), s.velocity, None,
                              s.gripper)  # fmt: skip
            if not run.phases or run.phases[-1][1] != s.phase:
                run.phases.append((now, s.phase))
            if s.phase == "done" and done_at is None:
                done_at = now
        if c.stabilize or now < saccade_until:
            cmd = stab.command(aim(q, base), base, twist, q, qd, gyro, now, latency)
            world.command_joints(list(cmd.velocity), "velocity", np.array([*cmd.velocity.values()]))
        world.step()
        if k % 10 == 0:
            track()
        phase = k % period
        stereo = (len(run.times) + 1) % c.localise_every == 0  # the frame being exposed
        if phase == 0 or (phase - period) in offsets:
            for f in FOVEAL if stereo else FOVEAL[:1]:
                img = render(f)
                light[f] = img if f not in light else light[f] + img
        if phase == 0:
            frames = {f: (light.pop(f) / len(offsets)).astype(np.uint8) for f in list(light)}
            if stereo:
                q, _, base, *_ = me.state()
                foveal_frame(frames, me.cameras(), q, base)
            run.times.append(world.time)
            run.blur.append(blur(frames[FOVEAL[0]]))
            if prev is not None:
                run.flow.append(flow_rmse_deg_s(prev, frames[FOVEAL[0]], deg_per_px, fps))
            prev = frames[FOVEAL[0]]
            if len(run.times) % 30 == 1:
                run.strip.append((world.time, prev))
        if k % p_period == 0:
            frames = {}
            for f in PERIPHERAL:
                renderer.snapshot(world.data, world.cameras[f])
                frames[f] = renderer.render(depth=False)[0]
            peripheral_frame(frames, me.cameras())
        if progress is not None and k % 100 == 0:
            progress(k / steps)
        if done_at is not None and world.time > done_at + c.carry_s:
            break
    renderer.close()
    track()
    t, lift, near, closure = np.asarray(run.cup_track).T
    run.lift_m = float(lift[-1])
    run.hold_m = float(near[t >= t[-1] - c.grasp_hold_s].max())
    run.gripper_max = float(closure.max())
    run.grasped = run.lift_m >= c.grasp_lift and run.hold_m <= c.grasp_near
    if progress is not None:
        progress(1.0)
    return run


def fixating(run: GraspRun, shift_s: float = 0.35) -> np.ndarray:
    """Per flow sample (frame pair): whether the gaze was holding a target, i.e. not within
    ``shift_s`` of a gaze shift to a new target (a saccade sweeps the image on purpose, in both
    modes alike; what stabilisation is for is the image while the gaze holds)."""
    t = np.asarray(run.times[1:])
    shifts = np.array([s for s, _ in run.targets])
    if not len(shifts):
        return np.ones(len(t), bool)
    since = t[:, None] - shifts[None, :]
    return ~((since >= -0.02) & (since < shift_s)).any(axis=1)


def _stats(values: np.ndarray) -> dict:
    v = values if len(values) else np.zeros(1)
    return {"mean": float(v.mean()), "std": float(v.std()), "max": float(v.max())}


def summarise(run: GraspRun, config: GraspExperimentConfig) -> dict:
    """metrics.json of one run: the issue's keys plus what explains them. ``flow_rmse_deg_s``
    (Table 5.1) is over the frames while the gaze holds a target; ``flow_rmse_all_deg_s`` over
    every frame, gaze shifts included. ``grasped`` is judged on MuJoCo's state: ``lift_m`` (the
    cup's height above where it stood, at the end), ``hold_m`` (its largest distance to the
    grasp site over the last ``grasp_hold_s``); ``gripper_max`` is the fingers' largest closure
    (0 open … 1 closed on nothing)."""
    flow = np.asarray(run.flow)
    return {
        "grasped": run.grasped,
        "lift_m": run.lift_m,
        "hold_m": run.hold_m,
        "gripper_max": run.gripper_max,
        "first_localised_s": run.first_localised_s,
        "acuity_raised_s": run.acuity_raised_s,
        "acuity_reached_s": run.acuity_reached_s,
        "uncertainty": [[round(t, 3), s] for t, s in run.uncertainty],
        "flow_rmse_deg_s": _stats(flow[fixating(run)]),
        "flow_rmse_all_deg_s": _stats(flow),
        "blur": {"mean": float(np.mean(run.blur)) if run.blur else 0.0},
        "localisation_success": float(np.mean(run.found)) if run.found else 0.0,
        "phases": [[round(t, 3), p] for t, p in run.phases],
        "gaze_shifts": [[round(t, 3), n] for t, n in run.targets],
        "config": dataclasses.asdict(config),
    }
