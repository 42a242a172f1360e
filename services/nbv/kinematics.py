"""Head inverse kinematics for a view (thesis 4.1: "the gaze direction is set to the camera
orientation R using inverse kinematics"): with the platform at the view's pose (Eq. 4.2, 4.3),
find the torso height and neck angles that bring the camera to the view's height and its optical
axis through the sphere's centre, within the joint limits. pinocchio on the robot's MJCF; the
solver itself runs on the camera's joint chain taken out of it (constant transforms between
the 1-DoF joints, checked against pinocchio), compiled: a planning step solves hundreds of
views, ~60 forward kinematics each, which through pinocchio's Python binding cost ~1 s."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from numba import njit

from services.common.robots import camera_mount

#: the joints the view is reached with, per robot: (height, pan, tilt)
HEAD_JOINTS = {
    "armar6": ("torso_lift", "neck_yaw", "neck_pitch"),
    "armar3": ("hip_yaw", "neck_yaw", "neck_upper_pitch"),
}


@dataclass
class HeadSolution:
    joints: dict[str, float]
    T_world_camera: np.ndarray
    aim_error: float  # rad between the optical axis and the direction to the target
    height_error: float  # m between the camera and the view's height


_PRISMATIC, _REVOLUTE = 0, 1
_FD = 1e-6  # the finite difference of the Jacobian
_ITERATIONS = 30


@njit(cache=True, nogil=True, inline="always")
def _mul_into(A, B, out):
    """out = A · B of 4×4 homogeneous transforms (loops, no allocation: a solve makes
    thousands of these)."""
    for i in range(3):
        a0, a1, a2, a3 = A[i, 0], A[i, 1], A[i, 2], A[i, 3]
        for j in range(4):
            out[i, j] = a0 * B[0, j] + a1 * B[1, j] + a2 * B[2, j]
        out[i, 3] += a3
    out[3, 0], out[3, 1], out[3, 2], out[3, 3] = 0.0, 0.0, 0.0, 1.0


@njit(cache=True, nogil=True)
def _fk(consts, kinds, axes, order, base, q, T, buf):
    """T_world_camera of the chain into ``T``: planar base (x, y, yaw) · C0 · X0(q) · C1 ·
    X1(q) · C2 · X2(q) · C3, the joint transforms X about / along their unit axes, ``order``
    the index into ``q`` of each joint along the chain; ``buf``: (3, 4, 4) scratch."""
    B, X, S = buf[0], buf[1], buf[2]
    c, s = math.cos(base[2]), math.sin(base[2])
    X[:] = 0.0
    X[0, 0], X[0, 1], X[1, 0], X[1, 1], X[2, 2] = c, -s, s, c, 1.0
    X[0, 3], X[1, 3], X[3, 3] = base[0], base[1], 1.0
    _mul_into(X, consts[0], T)
    for i in range(3):
        a, v = axes[i], q[order[i]]
        X[:] = 0.0
        X[0, 0], X[1, 1], X[2, 2], X[3, 3] = 1.0, 1.0, 1.0, 1.0
        if kinds[i] == _PRISMATIC:
            X[0, 3], X[1, 3], X[2, 3] = a[0] * v, a[1] * v, a[2] * v
        else:  # Rodrigues: I + sin·K + (1 − cos)·K², K the cross-product matrix of a
            sv, cv = math.sin(v), 1.0 - math.cos(v)
            S[:] = 0.0
            S[0, 1], S[0, 2], S[1, 0], S[1, 2], S[2, 0], S[2, 1] = (
                -a[2], a[1], a[2], -a[0], -a[1], a[0],
            )  # fmt: skip
            for r in range(3):
                for k in range(3):
                    KK = S[r, 0] * S[0, k] + S[r, 1] * S[1, k] + S[r, 2] * S[2, k]
                    X[r, k] += sv * S[r, k] + cv * KK
        _mul_into(T, X, B)
        _mul_into(B, consts[i + 1], T)


@njit(cache=True, nogil=True)
def _residual(consts, kinds, axes, order, base, q, target, height, T, buf, out):
    """(camera height − height, x and y of the unit direction to the target in the camera
    frame) into ``out``."""
    _fk(consts, kinds, axes, order, base, q, T, buf)
    w0, w1, w2 = target[0] - T[0, 3], target[1] - T[1, 3], target[2] - T[2, 3]
    d0 = T[0, 0] * w0 + T[1, 0] * w1 + T[2, 0] * w2
    d1 = T[0, 1] * w0 + T[1, 1] * w1 + T[2, 1] * w2
    d2 = T[0, 2] * w0 + T[1, 2] * w1 + T[2, 2] * w2
    n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    out[0], out[1], out[2] = T[2, 3] - height, d0 / n, d1 / n


@njit(cache=True, nogil=True)
def _step(J, r, rcond):
    """The least-squares step J⁺·(−r): Gaussian elimination (partial pivoting) when J is
    well conditioned, where it is the same solution to rounding, else numpy's SVD lstsq
    (minimum norm, as ``lstsq`` gives for a rank-deficient J) — a LAPACK call per
    iteration cost most of the solver's time."""
    A = J.copy()
    b = -r
    scale = np.abs(A).max()
    for c in range(3):
        p = c + np.argmax(np.abs(A[c:, c]))
        if abs(A[p, c]) <= 1e-9 * scale:
            return np.linalg.lstsq(J, -r, rcond)[0]
        if p != c:
            for k in range(3):
                A[c, k], A[p, k] = A[p, k], A[c, k]
            b[c], b[p] = b[p], b[c]
        for rr in range(c + 1, 3):
            f = A[rr, c] / A[c, c]
            for k in range(c, 3):
                A[rr, k] -= f * A[c, k]
            b[rr] -= f * b[c]
    x = np.empty(3)
    for c in range(2, -1, -1):
        acc = b[c]
        for k in range(c + 1, 3):
            acc -= A[c, k] * x[k]
        x[c] = acc / A[c, c]
    return x


@njit(cache=True, nogil=True)
def _solve(consts, kinds, axes, order, lo, hi, bases, targets, heights):
    """Gauss-Newton per view (``HeadIK.solve_pinocchio``'s, step for step): the joints (n, 3),
    the camera poses (n, 4, 4), the aim errors (rad) and the height errors (m)."""
    n = bases.shape[0]
    qs, Ts = np.empty((n, 3)), np.empty((n, 4, 4))
    aims, errs = np.empty(n), np.empty(n)
    rcond = 3 * np.finfo(np.float64).eps  # numpy's default for a 3×3 least-squares problem
    T, buf = np.empty((4, 4)), np.empty((3, 4, 4))
    r, rj, J, dq = np.empty(3), np.empty(3), np.empty((3, 3)), np.empty(3)
    for v in range(n):
        base, target, height = bases[v], targets[v], heights[v]
        q = (lo + hi) / 2
        for _ in range(_ITERATIONS):
            _residual(consts, kinds, axes, order, base, q, target, height, T, buf, r)
            for j in range(3):
                dq[:] = q
                dq[j] += _FD
                _residual(consts, kinds, axes, order, base, dq, target, height, T, buf, rj)
                for i in range(3):
                    J[i, j] = (rj[i] - r[i]) / _FD
            step = _step(J, r, rcond)
            q = np.minimum(np.maximum(q + step, lo), hi)
            if np.abs(step).max() < 1e-7:
                break
        _fk(consts, kinds, axes, order, base, q, T, buf)
        to = target - T[:3, 3]
        cos_aim = (T[0, 2] * to[0] + T[1, 2] * to[1] + T[2, 2] * to[2]) / np.linalg.norm(to)
        qs[v], Ts[v] = q, T
        aims[v] = math.acos(min(max(cos_aim, -1.0), 1.0))
        errs[v] = abs(T[2, 3] - height)
    return qs, Ts, aims, errs


class HeadIK:
    def __init__(self, mjcf: Path, camera: str, robot: str = "armar6") -> None:
        self.model = pin.buildModelFromMJCF(str(mjcf))
        self.data = self.model.createData()
        body, self.T_body_camera = camera_mount(mjcf, camera)
        self.body = self.model.getFrameId(body)
        self.names = HEAD_JOINTS[robot]
        ids = [self.model.getJointId(n) for n in self.names]
        self.idx = [self.model.joints[i].idx_q for i in ids]
        self.lo = self.model.lowerPositionLimit[self.idx]
        self.hi = self.model.upperPositionLimit[self.idx]
        base = self.model.getJointId("Composite_base_x")
        self.base_idx = self.model.joints[base].idx_q  # (x, y, yaw) follow
        self.chain = self._chain(ids, base)

    def _chain(self, ids: list[int], base: int):
        """(C0..C3, joint kinds, axes, order) of the camera's chain for ``_fk``, or None when
        it is not a planar base followed by 1-DoF joints or ``_fk`` disagrees with pinocchio
        (then ``solve`` goes through pinocchio, as slowly as it did)."""
        m, d = self.model, self.data
        chain, j = [], m.frames[self.body].parentJoint
        while j > 0:
            chain.append(j)
            j = m.parents[j]
        chain.reverse()
        if not chain or chain[0] != base or not set(ids) <= set(chain[1:]):
            return None
        q0 = pin.neutral(m)
        pin.forwardKinematics(m, d, q0)
        consts, kinds, axes, order = [], [], [], []
        C = pin.SE3.Identity()
        for j in chain[1:]:
            if j not in ids:  # a joint held at its neutral position: part of the constant
                C = C * d.liMi[j]
                continue
            if m.joints[j].nq != 1:
                return None
            consts.append(C * m.jointPlacements[j])
            C = pin.SE3.Identity()
            q1 = q0.copy()
            q1[m.joints[j].idx_q] += 1.0
            pin.forwardKinematics(m, d, q1)
            X = m.jointPlacements[j].inverse() * d.liMi[j]  # the joint's own motion at q = 1
            pin.forwardKinematics(m, d, q0)
            if np.allclose(X.rotation, np.eye(3), atol=1e-12):
                kinds.append(_PRISMATIC)
                axes.append(np.array(X.translation))
            else:
                kinds.append(_REVOLUTE)
                axes.append(np.array(pin.log3(X.rotation)))
            order.append(ids.index(j))
        consts.append(C * m.frames[self.body].placement)
        C = np.array([np.array(c.homogeneous) for c in consts])
        C[-1] = C[-1] @ self.T_body_camera
        out = (C, np.array(kinds, np.int64), np.array(axes), np.array(order, np.int64))
        rng = np.random.default_rng(0)
        for _ in range(20):
            b = rng.uniform([-3, -3, -math.pi], [3, 3, math.pi])
            q = rng.uniform(self.lo, self.hi)
            T = np.empty((4, 4))
            _fk(*out, b, q, T, np.empty((3, 4, 4)))
            if not np.allclose(T, self.camera_pose(tuple(b), q), atol=1e-9):
                return None
        return out

    def height_range(self) -> tuple[float, float]:
        """The camera heights the head joints reach over level ground (cached)."""
        if not hasattr(self, "_heights"):
            grid = np.stack(
                np.meshgrid(*[np.linspace(a, b, 7) for a, b in zip(self.lo, self.hi, strict=True)]),
                -1,
            )
            z = [self.camera_pose((0.0, 0.0, 0.0), q)[2, 3] for q in grid.reshape(-1, 3)]
            self._heights = (float(min(z)), float(max(z)))
        return self._heights

    def camera_pose(self, base: tuple[float, float, float], head: np.ndarray) -> np.ndarray:
        q = pin.neutral(self.model)
        q[self.base_idx : self.base_idx + 3] = base
        q[self.idx] = head
        pin.framesForwardKinematics(self.model, self.data, q)
        return self.data.oMf[self.body].homogeneous @ self.T_body_camera

    def _residual(self, base, head, target, height) -> np.ndarray:
        T = self.camera_pose(base, head)
        d = T[:3, :3].T @ (target - T[:3, 3])
        d /= np.linalg.norm(d)
        return np.array([T[2, 3] - height, d[0], d[1]])  # aim: x, y of the target's direction

    def solve(
        self,
        base: tuple[float, float, float],
        target: np.ndarray,
        height: float,
        aim_tol: float = math.radians(1.0),
        height_tol: float = 0.05,
    ) -> HeadSolution | None:
        """Joints that put the camera at ``height`` looking at ``target`` from ``base``, or
        None when the limits do not allow it (Gauss-Newton, clamped to the limits)."""
        return self.solve_many([base], [target], [height], aim_tol, height_tol)[0]

    def solve_many(
        self,
        bases,
        targets,
        heights,
        aim_tol: float = math.radians(1.0),
        height_tol: float = 0.05,
    ) -> list[HeadSolution | None]:
        """``solve`` for many views at once (one compiled call)."""
        bases = np.asarray(bases, np.float64).reshape(-1, 3)
        targets = np.asarray(targets, np.float64).reshape(-1, 3)
        heights = np.asarray(heights, np.float64).reshape(-1)
        if self.chain is None:
            return [
                self.solve_pinocchio(tuple(b), t, h, aim_tol, height_tol)
                for b, t, h in zip(bases, targets, heights, strict=True)
            ]
        lo, hi = np.asarray(self.lo, np.float64), np.asarray(self.hi, np.float64)
        qs, Ts, aims, errs = _solve(*self.chain, lo, hi, bases, targets, heights)
        return [
            HeadSolution(dict(zip(self.names, map(float, q), strict=True)), T, aim, err)
            if aim <= aim_tol and err <= height_tol
            else None
            for q, T, aim, err in zip(qs, Ts, aims.tolist(), errs.tolist(), strict=True)
        ]

    def solve_pinocchio(
        self,
        base: tuple[float, float, float],
        target: np.ndarray,
        height: float,
        aim_tol: float = math.radians(1.0),
        height_tol: float = 0.05,
    ) -> HeadSolution | None:
        """``solve`` through pinocchio's forward kinematics: the reference (and the way for a
        chain ``_fk`` cannot take)."""
        target = np.asarray(target, float)
        q = (self.lo + self.hi) / 2
        weights = np.array([1.0, 1.0, 1.0])
        for _ in range(30):
            r = self._residual(base, q, target, height)
            J = np.empty((3, 3))
            for j in range(3):
                dq = np.zeros(3)
                dq[j] = 1e-6
                J[:, j] = (self._residual(base, q + dq, target, height) - r) / 1e-6
            step = np.linalg.lstsq(J * weights, -r * weights, rcond=None)[0]
            q = np.clip(q + step, self.lo, self.hi)
            if np.abs(step).max() < 1e-7:
                break
        T = self.camera_pose(base, q)
        to = target - T[:3, 3]
        aim = math.acos(float(np.clip(T[:3, 2] @ to / np.linalg.norm(to), -1.0, 1.0)))
        err = abs(T[2, 3] - height)
        if aim > aim_tol or err > height_tol:
            return None
        return HeadSolution(dict(zip(self.names, map(float, q), strict=True)), T, aim, err)
