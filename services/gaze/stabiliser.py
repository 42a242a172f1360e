"""The gaze stabiliser (thesis 5.2, 5.3; Habra et al. 2017): hold the fixation point x_des on
the optical axis of the chosen cameras while the rest of the robot moves.

Head and eye velocities q̇_h solve J_h·q̇_h = ẋ, the virtual end-effectors' wanted velocity:

    ẋ = K·e                       feedback on the fixation error e = x_des − x_vee
        − J_o·q̇_o                 feed-forward: the self-induced motion predicted from the
                                   measured velocities of the other joints and the odometry
        − ω_u × (x_vee − p_imu)    VOR: the head rotation the gyro measures and the forward
                                   model did not predict (reafference: ω_u = ω_gyro − J_ω·v)

by weighted damped least squares, q̇_h = W⁻¹J_hᵀ(J_h W⁻¹J_hᵀ + λ²I)⁻¹ẋ, with the eye joints'
weight 8× the neck's (the neck moves first; the eyes only where they must, 5.2), the joints
drawn to mid-range in the null space; joints at their speed or position limits are held there
and the rest solve the task.

Real sensors (``sensing``): the gyro's bias is estimated while the head is still and taken off
its readings; the joint state, measured ``latency`` s before the control step, is carried
forward to it by its velocities.

OKR: the retinal slip s the forward model did not predict (``okr.RetinalSlip``: the target
drifting across the image) moves the point held, x_des + o, by k_okr·d·(x_cam·s_x + y_cam·s_y)·Δt
(the image says the target is elsewhere than the model thinks; o leaks back over 10 s).
Pure: arrays in, velocities out."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from services.gaze.kinematics import EYE_JOINTS, GazeKinematics, cross
from services.gaze.sensing import GyroBias, GyroBiasConfig, bias_update, predicted


@dataclass
class StabiliserConfig:
    joints: Sequence[str]  # the head and eye joints commanded
    cameras: Sequence[str]  # whose optical axes hold the fixation point
    gain: float = 20.0  # K, 1/s
    damping: float = 0.02  # λ
    eye_weight: float = 8.0  # W of the eye joints, the neck's being 1 (5.2)
    vor_gain: float = 1.0
    okr_gain: float = 1.0  # the measured drift taken in full (less lags, more overshoots)
    okr_leak: float = 10.0  # s: the OKR offset decays with this time constant
    feedforward: bool = True  # predict self-induced motion from joint velocities
    odometry: bool = True  # … and from the platform's odometry
    speed: Mapping[str, float] = field(default_factory=dict)  # rad/s per joint (default 2)
    centring: float = 1.0  # 1/s, the null-space pull towards mid-range
    limit_time: float = 0.05  # s: joints approach their range limits as if to stop in this
    #: the gyro's bias, estimated while still (None: the readings taken as they are)
    gyro_bias: GyroBiasConfig | None = field(default_factory=GyroBiasConfig)
    max_prediction: float = 0.05  # s: a joint state older than this is not carried further


@dataclass
class GazeCommand:
    velocity: dict[str, float]
    error_rad: dict[str, float]  # gaze angle error per camera
    unpredicted: np.ndarray  # ω_u, rad/s (world)
    array: np.ndarray | None = None  # the velocities in the order of the config's joints


class GazeStabiliser:
    def __init__(self, kinematics: GazeKinematics, config: StabiliserConfig) -> None:
        self.kin, self.c = kinematics, config
        self.head = [kinematics.idx_v[n] for n in config.joints]
        weight = np.array([config.eye_weight if n in EYE_JOINTS else 1.0 for n in config.joints])
        self.w_inv = 1.0 / weight
        self.vmax = np.array([config.speed.get(n, 2.0) for n in config.joints])
        self.lower = np.array([kinematics.lower[n] for n in config.joints])
        self.upper = np.array([kinematics.upper[n] for n in config.joints])
        self.last_target: np.ndarray | None = None
        self.offset = np.zeros(3)  # OKR: where the image says the fixation point is, minus x_des
        self.stamp: float | None = None
        self.bias = GyroBias(config.gyro_bias) if config.gyro_bias is not None else None
        self.head_index = np.array(self.head, np.int64)
        #: K, feed-forward on/off, VOR gain, and the solve's limit time, centring and damping
        self.gains = np.array([config.gain, float(config.feedforward), config.vor_gain,
                               config.limit_time, config.centring, config.damping])  # fmt: skip
        self._no_bias = np.zeros(11)
        self._head_of_names: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray]] = {}

    def warm_up(self) -> None:
        """Compile the control step's kernels now (seconds on a machine's first run, read from
        numba's cache after), leaving the stabiliser as it was: a real-time loop must not
        stall for them on its first sample."""
        saved = (self.offset.copy(), self.stamp, self.last_target,
                 None if self.bias is None else self.bias.state.copy())  # fmt: skip
        zeros = dict.fromkeys(self.kin.joint_names, 0.0)
        self.command(np.array([1.5, 0.0, 1.0]), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), zeros, zeros,
                     np.zeros(3), 0.0, 0.001)  # fmt: skip
        self.offset, self.stamp, self.last_target = saved[:3]
        if self.bias is not None:
            self.bias.state[:] = saved[3]

    def observe_slip(self, camera: str, slip: np.ndarray, dt: float) -> None:
        """OKR: the slip (rad/s along ``camera``'s x and y) over the last ``dt`` s moves the held
        point across that camera's view, at the fixation distance (from the last update)."""
        T = self.kin.camera_pose(camera)
        d = (
            float(np.linalg.norm(self.last_target - T[:3, 3]))
            if self.last_target is not None
            else 1.5
        )
        self.offset += self.c.okr_gain * d * (T[:3, :2] @ (np.asarray(slip, float) * dt))

    def command(
        self,
        x_des: np.ndarray,
        base: Sequence[float],
        base_twist: Sequence[float],
        position: Mapping[str, float],
        velocity: Mapping[str, float],
        gyro: np.ndarray | None = None,
        stamp: float | None = None,
        latency: float = 0.0,
    ) -> GazeCommand:
        """Head and eye velocities for one control period. ``base``: odometry (x, y, yaw),
        ``base_twist`` its world velocity (vx, vy, yaw rate); ``position``/``velocity``: the
        measured joints, ``latency`` s old; ``gyro``: the head IMU's angular velocity (IMU
        frame) at the joints' instant, None without one; ``stamp``: the control step's time
        (for the OKR offset's leak)."""
        c, kin = self.c, self.kin
        target, base, twist, horizon = self._begin(x_des, base, base_twist, stamp, latency)
        if horizon > 0.0:  # the joints where they are now
            position = predicted(position, velocity, horizon)
        q = kin.configuration(base, position)
        v = kin.velocity(twist, velocity)
        q_head = np.array([position.get(n, 0.0) for n in c.joints])
        return self._finish(target, q, v, q_head, gyro, stamp)

    def command_of(
        self,
        x_des: np.ndarray,
        base: Sequence[float],
        base_twist: Sequence[float],
        names: tuple[str, ...],
        position: np.ndarray,
        velocity: np.ndarray,
        gyro: np.ndarray | None = None,
        stamp: float | None = None,
        latency: float = 0.0,
    ) -> GazeCommand:
        """``command`` with the measured joints as arrays in the order of ``names`` (a joint
        state's, as it arrives), the same numbers without a mapping built per step: the
        node's 1 kHz loop."""
        c, kin = self.c, self.kin
        target, base, twist, horizon = self._begin(x_des, base, base_twist, stamp, latency)
        position = np.asarray(position, float)
        velocity = np.asarray(velocity, float)
        if horizon > 0.0:  # (``predicted``, element by element)
            position = position + velocity * horizon
        q = kin.configuration_of(base, names, position)
        v = kin.velocity_of(twist, names, velocity)
        found, where = self._head_of(names)
        q_head = np.zeros(len(c.joints))
        q_head[found] = position[where]
        return self._finish(target, q, v, q_head, gyro, stamp)

    def _head_of(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
        """The commanded joints that ``names`` holds (indices into the config's joints) and
        where in ``names`` each is; cached per tuple of names."""
        found = self._head_of_names.get(names)
        if found is None:
            where = {n: i for i, n in enumerate(names)}
            mine = [k for k, n in enumerate(self.c.joints) if n in where]
            found = self._head_of_names[names] = (
                np.array(mine, np.int64),
                np.array([where[self.c.joints[k]] for k in mine], np.int64),
            )
        return found

    def _begin(
        self,
        x_des: np.ndarray,
        base: Sequence[float],
        base_twist: Sequence[float],
        stamp: float | None,
        latency: float,
    ) -> tuple[np.ndarray, Sequence[float], Sequence[float], float]:
        """The OKR offset's leak and the point held; the platform carried over the latency:
        (target, base, twist, the prediction's horizon)."""
        c = self.c
        if stamp is not None and self.stamp is not None:
            self.offset *= np.exp(-max(0.0, stamp - self.stamp) / c.okr_leak)
        self.stamp = stamp
        self.last_target = np.asarray(x_des, float)
        target = self.last_target + self.offset
        twist = base_twist if c.odometry else (0.0, 0.0, 0.0)
        horizon = min(max(latency, 0.0), c.max_prediction)
        if horizon > 0.0:  # the platform where it is now
            base = (base[0] + twist[0] * horizon, base[1] + twist[1] * horizon,
                    base[2] + twist[2] * horizon)  # fmt: skip
        return target, base, twist, horizon

    def _finish(
        self,
        target: np.ndarray,
        q: np.ndarray,
        v: np.ndarray,
        q_head: np.ndarray,
        gyro: np.ndarray | None,
        stamp: float | None,
    ) -> GazeCommand:
        """The control step at configuration ``q``, velocity ``v``."""
        c, kin = self.c, self.kin
        kin.update(q)
        frames, mounts, jacobians = kin.frames(c.cameras)
        M_imu, J_imu = kin.imu_frame()
        bias = self.bias
        qd, errors, omega_u = control_step(
            frames, mounts, jacobians, M_imu, J_imu, v, self.head_index, target, q_head,
            # (a copy: a decoded message's arrays are read-only views, another type to numba,
            # which would compile the kernel again at the first live sample)
            np.zeros(3) if gyro is None else np.array(gyro, float), gyro is not None,
            bias.state if bias is not None else self._no_bias, bias is not None,
            0.0 if stamp is None else float(stamp), stamp is not None,
            bias.params if bias is not None else self._no_bias, self.gains,
            self.lower, self.upper, self.vmax, self.w_inv,
        )  # fmt: skip
        return GazeCommand(
            dict(zip(c.joints, qd.tolist(), strict=True)),
            dict(zip(c.cameras, errors.tolist(), strict=True)),
            omega_u,
            qd,
        )

    def solve(self, J: np.ndarray, xd: np.ndarray, q: np.ndarray) -> np.ndarray:
        """q̇ = J#·ẋ + (I − J#·J)·q̇₀ with the weighted damped pseudo-inverse J# and q̇₀ pulling
        the joints towards the middle of their range in the task's null space; a joint that
        would pass its speed limit, or near its range's end faster than ``limit_time`` allows,
        is held at that bound and the task solved again with the others (saturation in the
        null space)."""
        c = self.c
        return saturated_solve(
            np.ascontiguousarray(J, np.float64), np.ascontiguousarray(xd, np.float64),
            np.asarray(q, np.float64), self.lower, self.upper, self.vmax, self.w_inv,
            float(c.limit_time), float(c.centring), float(c.damping),
        )  # fmt: skip


@njit(cache=True)
def saturated_solve(J, xd, q, lower, upper, vmax, w_inv, limit_time, centring, damping):
    """``GazeStabiliser.solve`` compiled (one control step's share of a 1 kHz budget): the
    weighted damped least squares with null-space centring, joints saturated one by one."""
    n, m = q.shape[0], xd.shape[0]
    # towards a limit no faster than reaching it in limit_time (an exponential approach),
    # away from one (or back from past it) at up to the speed limit
    lo = np.minimum(np.maximum((lower - q) / limit_time, -vmax), vmax)
    hi = np.minimum(np.maximum((upper - q) / limit_time, -vmax), vmax)
    centre = -centring * (q - (lower + upper) / 2)
    Jt = np.ascontiguousarray(J.T)  # a joint's column as a contiguous row
    free = np.ones(n, np.bool_)
    qd = np.zeros(n)
    for _ in range(n):
        # A = J_f W⁻¹ J_fᵀ + λ² I (m × m, symmetric positive definite); J# = W⁻¹ J_fᵀ A⁻¹, and
        # q̇_f = J#·rest + (I − J#·J_f)·centre_f = centre_f + J#·r with rest = ẋ − J_s·q̇_s (the
        # saturated joints' share) and r = rest − J_f·centre_f
        A = damping**2 * np.eye(m)
        r = xd.copy()
        for j in range(n):
            if free[j]:
                A += w_inv[j] * np.outer(Jt[j], Jt[j])
                r -= Jt[j] * centre[j]
            else:
                r -= Jt[j] * qd[j]
        y = np.linalg.solve(A, r)
        for j in range(n):
            if free[j]:
                qd[j] = centre[j] + w_inv[j] * np.dot(Jt[j], y)
        worst, over_max = -1, 1e-12
        for j in range(n):
            if free[j]:
                over = max(qd[j] - hi[j], lo[j] - qd[j])
                if over > over_max:
                    worst, over_max = j, over
        if worst < 0:
            break
        qd[worst] = min(max(qd[worst], lo[worst]), hi[worst])
        free[worst] = False
        if not free.any():
            break
    return np.minimum(np.maximum(qd, lo), hi)


@njit(cache=True)
def _matvec(A, x):
    """A·x by loops: small matrices, views of any layout (BLAS would cost more here)."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for j in range(A.shape[1]):
            out[i] += A[i, j] * x[j]
    return out


@njit(cache=True)
def control_step(frames, mounts, jacobians, M_imu, J_imu, v, head, x_des, q_head, gyro,
                 has_gyro, bias_state, has_bias, stamp, has_stamp, bias_params, gains, lower,
                 upper, vmax, w_inv):  # fmt: skip
    """One control step after the forward kinematics (``GazeStabiliser.command``), compiled:
    per camera c, with its body frame's placement ``frames[c]`` and world-aligned Jacobian
    ``jacobians[c]`` (6 × nv), the optical frame T = frames[c]·mounts[c]; the IMU's placement
    and Jacobian. Returns (q̇ of the head joints, the gaze angle error per camera, ω_u)."""
    gain, feedforward, vor_gain = gains[0], gains[1] > 0, gains[2]
    R_imu, p_imu = M_imu[:3, :3], M_imu[:3, 3].copy()
    w_model = _matvec(J_imu[3:], v)  # the forward model's angular velocity of the IMU (world)
    omega_u = np.zeros(3)
    if has_gyro:
        g = gyro.copy()
        if has_bias:  # still or not, as the forward model and the gyro say
            bias_update(bias_state, g, _matvec(R_imu.T, w_model), stamp, has_stamp, bias_params)
            g = g - bias_state[0:3]
        omega_u = _matvec(R_imu, g) - w_model
    v_other = v.copy()
    for j in head:
        v_other[j] = 0.0
    k, n, nv = frames.shape[0], head.shape[0], v.shape[0]
    rows = np.empty((2 * k, n))
    targets = np.empty(2 * k)
    errors = np.empty(k)
    for c in range(k):
        T = np.zeros((4, 4))
        for i in range(4):
            for j in range(4):
                for m in range(4):
                    T[i, j] += frames[c, i, m] * mounts[c, m, j]
        p, z = T[:3, 3].copy(), T[:3, 2].copy()
        to = x_des - p
        d = np.sqrt(np.sum(to**2))
        x_vee = p + d * z
        errors[c] = np.arctan2(np.sqrt(np.sum(cross(z, to) ** 2)), np.sum(z * to))
        e = to - d * z
        # the world velocity of x_vee fixed to the camera's body: J_lin − [x_vee − o]× J_ang
        J6 = jacobians[c]
        lever = x_vee - frames[c, :3, 3]
        J = np.empty((3, nv))
        for col in range(nv):
            J[:, col] = J6[:3, col] - cross(lever, J6[3:, col].copy())
        xd = gain * e
        if feedforward:
            xd = xd - _matvec(J, v_other)
        xd = xd - vor_gain * cross(omega_u, x_vee - p_imu)
        for i in range(2):  # across the optical axis only: the camera's x and y (lateral())
            for j in range(n):
                rows[2 * c + i, j] = (
                    T[0, i] * J[0, head[j]] + T[1, i] * J[1, head[j]] + (T[2, i] * J[2, head[j]])
                )
            targets[2 * c + i] = T[0, i] * xd[0] + T[1, i] * xd[1] + T[2, i] * xd[2]
    qd = saturated_solve(rows, targets, q_head, lower, upper, vmax, w_inv, gains[3],
                         gains[4], gains[5])  # fmt: skip
    return qd, errors, omega_u
