"""The robot's own body in its camera (issue 16): the shapes of the robot's MJCF (capsules,
boxes, spheres, cylinders), placed by pinocchio's forward kinematics at the joint positions the
frame was captured with, and every depth pixel whose point lies inside one of them (grown by a
margin) masked before the cloud is built, so arms and hands are never perceived as primitives.

Poses are taken relative to the camera on the same kinematic tree, so the platform's odometry
does not enter: only the joints between the camera and each link do."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from services.common.robots import camera_mount

BASE_JOINT = "Composite_base_x"


@dataclass(frozen=True)
class Shape:
    body: str
    kind: str  # sphere | capsule | box | cylinder
    T_body: np.ndarray  # 4 × 4: the shape's frame in its body (z its axis)
    size: np.ndarray  # sphere (r,), capsule / cylinder (r, half length), box (half x, y, z)

    @property
    def radius(self) -> float:
        """Of a sphere around it, centred at its frame's origin."""
        if self.kind == "sphere":
            return float(self.size[0])
        if self.kind == "box":
            return float(np.linalg.norm(self.size))
        return float(np.hypot(self.size[0], self.size[1]) + (self.kind == "capsule") * self.size[0])


def _floats(text: str | None, default: str) -> np.ndarray:
    return np.array([float(v) for v in (text or default).split()])


def _shape(body: str, geom: ET.Element) -> Shape | None:
    kind = geom.get("type", "sphere")
    size = _floats(geom.get("size"), "0")
    T = np.eye(4)
    if geom.get("fromto") is not None:
        a, b = np.split(_floats(geom.get("fromto"), ""), 2)
        axis = b - a
        length = float(np.linalg.norm(axis))
        z = axis / length
        x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0], z)
        x /= np.linalg.norm(x)
        T[:3, :3] = np.column_stack([x, np.cross(z, x), z])
        T[:3, 3] = (a + b) / 2
        size = np.array([size[0], length / 2])
    else:
        T[:3, 3] = _floats(geom.get("pos"), "0 0 0")
    if kind not in ("sphere", "capsule", "box", "cylinder"):
        return None
    return Shape(body, kind, T, size)


def robot_shapes(mjcf: Path) -> list[Shape]:
    """Every shape of the robot's bodies (visual and collision: their union is the body)."""
    shapes = []
    for body in ET.parse(mjcf).getroot().iter("body"):
        for geom in body.findall("geom"):
            s = _shape(body.get("name"), geom)
            if s is not None:
                shapes.append(s)
    return shapes


def _inside(kind: str, size: np.ndarray, p: np.ndarray, margin: float) -> np.ndarray:
    """Points ``p`` (n × 3, in the shape's frame) inside the shape grown by ``margin``."""
    if kind == "sphere":
        return np.einsum("ij,ij->i", p, p) <= (size[0] + margin) ** 2
    if kind == "box":
        return (np.abs(p) <= size + margin).all(axis=1)
    r2 = np.einsum("ij,ij->i", p[:, :2], p[:, :2])
    if kind == "cylinder":
        return (r2 <= (size[0] + margin) ** 2) & (np.abs(p[:, 2]) <= size[1] + margin)
    dz = np.maximum(np.abs(p[:, 2]) - size[1], 0.0)  # capsule: distance to the segment
    return r2 + dz * dz <= (size[0] + margin) ** 2


class RobotBody:
    """The robot's shapes, posed by its joints; ``mask`` finds them in a depth image."""

    def __init__(self, mjcf: Path, margin: float = 0.02) -> None:
        self.mjcf, self.margin = mjcf, margin
        self.model = pin.buildModelFromMJCF(str(mjcf))
        self.data = self.model.createData()
        m = self.model
        self.idx_q = {
            m.names[i]: m.joints[i].idx_q for i in range(1, m.njoints) if m.names[i] != BASE_JOINT
        }
        body = pin.FrameType.BODY
        self.shapes = [s for s in robot_shapes(mjcf) if m.existFrame(s.body, body)]
        self.frames = [m.getFrameId(s.body, body) for s in self.shapes]
        self._mounts: dict[str, tuple[int, np.ndarray]] = {}

    def _mount(self, camera: str) -> tuple[int, np.ndarray]:
        if camera not in self._mounts:
            body, T = camera_mount(self.mjcf, camera)
            self._mounts[camera] = (self.model.getFrameId(body, pin.FrameType.BODY), T)
        return self._mounts[camera]

    def shapes_in_camera(self, camera: str, joints: Mapping[str, float]) -> list[np.ndarray]:
        """T_camera_shape (optical frame) of every shape at these joint positions."""
        q = pin.neutral(self.model)
        for n, v in joints.items():
            if n in self.idx_q:
                q[self.idx_q[n]] = v
        pin.framesForwardKinematics(self.model, self.data, q)
        frame, T_body_optical = self._mount(camera)
        T_camera_world = np.linalg.inv(self.data.oMf[frame].homogeneous @ T_body_optical)
        return [
            T_camera_world @ self.data.oMf[f].homogeneous @ s.T_body
            for f, s in zip(self.frames, self.shapes, strict=True)
        ]

    def mask(
        self,
        depth: np.ndarray,
        fx: float,
        fy: float,
        cx: float,
        cy: float,
        camera: str,
        joints: Mapping[str, float],
    ) -> np.ndarray:
        """Boolean (h, w): pixels whose depth point lies inside the robot's body. Each shape is
        tested only on the pixels its bounding sphere covers."""
        z = np.asarray(depth, np.float32)
        h, w = z.shape
        out = np.zeros((h, w), bool)
        for s, T in zip(self.shapes, self.shapes_in_camera(camera, joints), strict=True):
            c, r = T[:3, 3], s.radius + self.margin
            if c[2] + r <= 0.0:
                continue  # behind the camera
            if c[2] - r > 1e-3:
                near = c[2] - r
                u0, u1 = fx * (c[0] - r) / near + cx, fx * (c[0] + r) / near + cx
                v0, v1 = fy * (c[1] - r) / near + cy, fy * (c[1] + r) / near + cy
                u0, u1 = max(int(np.floor(min(u0, u1))), 0), min(int(np.ceil(max(u0, u1))) + 1, w)
                v0, v1 = max(int(np.floor(min(v0, v1))), 0), min(int(np.ceil(max(v0, v1))) + 1, h)
            else:  # reaching around the camera: all of it
                u0, u1, v0, v1 = 0, w, 0, h
            if u0 >= u1 or v0 >= v1:
                continue
            zz = z[v0:v1, u0:u1]
            ok = np.isfinite(zz) & (zz > 0) & (zz <= c[2] + r)  # nothing deeper can be inside
            if not ok.any():
                continue
            vv, uu = np.nonzero(ok)
            d = zz[vv, uu].astype(np.float64)
            p = np.column_stack([(uu + u0 - cx) / fx * d, (vv + v0 - cy) / fy * d, d])
            local = (p - T[:3, 3]) @ T[:3, :3]
            hit = _inside(s.kind, s.size, local, self.margin)
            out[vv[hit] + v0, uu[hit] + u0] = True
        return out
