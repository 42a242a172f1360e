"""Head inverse kinematics for a view (thesis 4.1: "the gaze direction is set to the camera
orientation R using inverse kinematics"): with the platform at the view's pose (Eq. 4.2, 4.3),
find the torso height and neck angles that bring the camera to the view's height and its optical
axis through the sphere's centre, within the joint limits. pinocchio on the robot's MJCF."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

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
