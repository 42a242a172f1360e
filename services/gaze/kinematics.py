"""Forward kinematics of the head's cameras and the fixation Jacobian (thesis 5.2): the gaze
task as the control of a virtual end-effector on the gaze line (Omrčen & Ude 2010), the point
at the fixation distance along a camera's optical axis. pinocchio on the robot's MJCF."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import pinocchio as pin
from numba import njit

from services.common.robots import camera_mount

#: the joints the gaze controller commands, per robot (neck first, then the eyes)
HEAD_JOINTS = {
    "armar3": (
        "neck_lower_pitch", "neck_roll", "neck_yaw", "neck_upper_pitch",
        "eye_tilt", "eye_pan_left", "eye_pan_right",
    ),
    "armar6": ("neck_yaw", "neck_pitch"),
}  # fmt: skip
EYE_JOINTS = frozenset({"eye_tilt", "eye_pan_left", "eye_pan_right"})
BASE_JOINT = "Composite_base_x"  # x, y, yaw of the platform: pinocchio's name for the three


@njit(cache=True)
def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a × b of two 3-vectors (np.cross costs ten times as much on one pair; compiled, so the
    gaze's compiled control step can call it)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


def skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


class GazeKinematics:
    """The robot's kinematic tree (platform x, y, yaw + every joint); ``update`` with the
    measured configuration, then poses and Jacobians (world-aligned) of the cameras, the IMU
    and virtual end-effectors."""

    def __init__(self, mjcf: Path, cameras: Sequence[str], imu: str = "imu") -> None:
        self.model = pin.buildModelFromMJCF(str(mjcf))
        self.data = self.model.createData()
        m = self.model
        self.joint_names = [m.names[i] for i in range(1, m.njoints) if m.names[i] != BASE_JOINT]
        self.idx_q = {n: m.joints[m.getJointId(n)].idx_q for n in self.joint_names}
        self.idx_v = {n: m.joints[m.getJointId(n)].idx_v for n in self.joint_names}
        base = m.joints[m.getJointId(BASE_JOINT)]
        self.base_q, self.base_v = base.idx_q, base.idx_v
        self.lower = {n: float(m.lowerPositionLimit[self.idx_q[n]]) for n in self.joint_names}
        self.upper = {n: float(m.upperPositionLimit[self.idx_q[n]]) for n in self.joint_names}
        self.cameras = {}
        for c in cameras:
            body, T = camera_mount(mjcf, c)
            self.cameras[c] = (m.getFrameId(body), T)
        self.imu = m.getFrameId(imu)
        self.q = pin.neutral(m)
        self._neutral = pin.neutral(m)
        #: per tuple of joint names (a joint state's): ``joint_indices``
        self._indices: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def configuration(self, base: Sequence[float], joints: Mapping[str, float]) -> np.ndarray:
        """q from the platform pose (x, y, yaw) and named joint positions (others neutral)."""
        q = pin.neutral(self.model)
        q[self.base_q : self.base_q + 3] = base
        for n, v in joints.items():
            if n in self.idx_q:
                q[self.idx_q[n]] = v
        return q

    def velocity(self, base_twist: Sequence[float], joints: Mapping[str, float]) -> np.ndarray:
        """v from the platform's world velocity (vx, vy, yaw rate) and named joint velocities."""
        v = np.zeros(self.model.nv)
        v[self.base_v : self.base_v + 3] = base_twist
        for n, w in joints.items():
            if n in self.idx_v:
                v[self.idx_v[n]] = w
        return v

    def joint_indices(self, names: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For joint values in the order of ``names`` (a joint state's): which of them are the
        model's joints (indices into ``names``), and their indices in q and in v (cached per
        tuple of names: the 1 kHz control step's joint states all name the same joints)."""
        found = self._indices.get(names)
        if found is None:
            mine = [i for i, n in enumerate(names) if n in self.idx_q]
            found = self._indices[names] = (
                np.array(mine, np.int64),
                np.array([self.idx_q[names[i]] for i in mine], np.int64),
                np.array([self.idx_v[names[i]] for i in mine], np.int64),
            )
        return found

    def configuration_of(
        self, base: Sequence[float], names: tuple[str, ...], values: np.ndarray
    ) -> np.ndarray:
        """``configuration`` from joint values as an array in the order of ``names``."""
        mine, idx_q, _ = self.joint_indices(names)
        q = self._neutral.copy()
        q[self.base_q : self.base_q + 3] = base
        q[idx_q] = values[mine]
        return q

    def velocity_of(
        self, base_twist: Sequence[float], names: tuple[str, ...], values: np.ndarray
    ) -> np.ndarray:
        """``velocity`` from joint velocities as an array in the order of ``names``."""
        mine, _, idx_v = self.joint_indices(names)
        v = np.zeros(self.model.nv)
        v[self.base_v : self.base_v + 3] = base_twist
        v[idx_v] = values[mine]
        return v

    def update(self, q: np.ndarray) -> None:
        self.q = np.asarray(q, float)
        pin.computeJointJacobians(self.model, self.data, self.q)
        pin.updateFramePlacements(self.model, self.data)

    def frames(self, cameras: Sequence[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For each camera, at the last ``update``: its body frame's placement (4 × 4), the
        optical frame's mount in it (4 × 4) and the body frame's world-aligned Jacobian
        (6 × nv), stacked: the compiled control step's inputs."""
        k, nv = len(cameras), self.model.nv
        placements, mounts, jacobians = (
            np.empty((k, 4, 4)),
            np.empty((k, 4, 4)),
            np.empty((k, 6, nv)),
        )
        for i, c in enumerate(cameras):
            frame, T = self.cameras[c]
            placements[i] = self.data.oMf[frame].homogeneous
            mounts[i] = T
            jacobians[i] = pin.getFrameJacobian(self.model, self.data, frame,
                                                pin.LOCAL_WORLD_ALIGNED)  # fmt: skip
        return placements, mounts, jacobians

    def imu_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """The IMU's placement (4 × 4) and its world-aligned Jacobian (6 × nv)."""
        J = pin.getFrameJacobian(self.model, self.data, self.imu, pin.LOCAL_WORLD_ALIGNED)
        return self.data.oMf[self.imu].homogeneous, J

    def camera_pose(self, camera: str) -> np.ndarray:
        """T_world_optical (x right, y down, z forward) of a camera."""
        frame, T = self.cameras[camera]
        return self.data.oMf[frame].homogeneous @ T

    def point_jacobian(self, frame: int, point: np.ndarray) -> np.ndarray:
        """3 × nv: the world velocity of a point (world coordinates) fixed to the frame's body."""
        J = pin.getFrameJacobian(self.model, self.data, frame, pin.LOCAL_WORLD_ALIGNED)
        lever = np.asarray(point) - self.data.oMf[frame].translation
        return J[:3] - skew(lever) @ J[3:]

    def fixation(self, camera: str, x_des: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """(error x_des − x_vee, its Jacobian J_vee (3 × nv), the gaze angle error in rad) of the
        virtual end-effector x_vee = p + d·z: the point at the target's distance d along the
        camera's optical axis z (5.2). ẋ_vee = J_vee·v with d held. (Only the two components
        across the optical axis are a gaze error: see ``lateral``.)"""
        T = self.camera_pose(camera)
        p, z = T[:3, 3], T[:3, 2]
        to = np.asarray(x_des, float) - p
        d = float(np.linalg.norm(to))
        x_vee = p + d * z
        angle = float(np.arctan2(np.linalg.norm(cross(z, to)), z @ to))
        return to - d * z, self.point_jacobian(self.cameras[camera][0], x_vee), angle

    def imu_rotation(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(R_world_imu, the IMU's position, J_ω: 3 × nv world angular velocity of its body)."""
        J = pin.getFrameJacobian(self.model, self.data, self.imu, pin.LOCAL_WORLD_ALIGNED)
        M = self.data.oMf[self.imu]
        return M.rotation.copy(), M.translation.copy(), J[3:]

    def lateral(self, camera: str, x_des: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """``fixation`` along the camera's x and y axes only (2 and 2 × nv): along the optical
        axis the virtual end-effector has nothing to hold, and asking it to would spend joint
        motion (the eyes') on the distance."""
        e, J, angle = self.fixation(camera, x_des)
        R = self.camera_pose(camera)[:3, :2].T
        return R @ e, R @ J, angle

    def reachable_directions(
        self, camera: str, joints: Sequence[str], samples: int = 20_000, seed: int = 0
    ) -> np.ndarray:
        """Optical-axis directions of ``camera`` in the platform frame (platform at the origin)
        over uniform random samples of the joints' ranges: where the head can look (5.1
        prunes the ego-sphere to these)."""
        rng = np.random.default_rng(seed)
        lo = np.array([self.lower[n] for n in joints])
        hi = np.array([self.upper[n] for n in joints])
        frame, T = self.cameras[camera]
        out = np.empty((samples, 3))
        for i, q_j in enumerate(rng.uniform(lo, hi, (samples, len(joints)))):
            q = self.configuration((0.0, 0.0, 0.0), dict(zip(joints, q_j, strict=True)))
            pin.framesForwardKinematics(self.model, self.data, q)
            out[i] = self.data.oMf[frame].rotation @ T[:3, 2]
        return out
