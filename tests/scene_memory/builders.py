"""Synthetic primitives and observations for the scene-memory tests: surface points sampled
on a known shape, wrapped as perception would send them, seen by a camera above the scene."""

from __future__ import annotations

import numpy as np

from schemas import (
    BoxModel,
    CameraIntrinsics,
    CylinderModel,
    Obb,
    PlaneModel,
    Primitive,
    SceneObservation,
    SupportEdge,
)

RNG = np.random.default_rng(7)
INTRINSICS = CameraIntrinsics(width=640, height=480, fx=580.0, fy=580.0, cx=319.5, cy=239.5)


def camera_above(x: float = 0.9, y: float = 0.0, height: float = 2.6) -> np.ndarray:
    """T_world_camera looking straight down from (x, y, height); sees ±1.2 m at table height."""
    T = np.eye(4)
    T[:3, :3] = np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]])
    T[:3, 3] = [x, y, height]
    return T


def plane(pid: int, x: tuple[float, float], y: tuple[float, float], z: float) -> Primitive:
    """A level rectangle [x0, x1] × [y0, y1] at height z."""
    n = 1500
    pts = np.column_stack(
        [RNG.uniform(*x, n), RNG.uniform(*y, n), z + RNG.normal(0, 0.002, n)]
    ).astype(np.float32)
    centre = np.array([(x[0] + x[1]) / 2, (y[0] + y[1]) / 2, z])
    return Primitive(
        id=pid,
        model=PlaneModel(normal=np.array([0.0, 0, 1]), d=-z),
        obb=Obb(
            center=centre, rotation=np.eye(3), extent=np.array([x[1] - x[0], y[1] - y[0], 0.004])
        ),
        inlier_count=n,
        inliers=pts,
    )


def cylinder(
    pid: int, base: tuple[float, float, float], radius: float, height: float, side: float
) -> Primitive:
    """An upright cylinder standing on ``base``, seen from direction ``side`` (radians): the
    half of its mantle that faces it."""
    n = 1200
    a = side + RNG.uniform(-np.pi / 2, np.pi / 2, n)
    h = RNG.uniform(0, height, n)
    b = np.asarray(base)
    pts = np.column_stack([b[0] + radius * np.cos(a), b[1] + radius * np.sin(a), b[2] + h])
    centre = b + np.array([0, 0, height / 2])
    return Primitive(
        id=pid,
        model=CylinderModel(
            center=centre, axis=np.array([0.0, 0, 1]), radius=radius, height=height
        ),
        obb=Obb(
            center=centre, rotation=np.eye(3), extent=np.array([2 * radius, 2 * radius, height])
        ),
        inlier_count=n,
        inliers=pts.astype(np.float32),
    )


def box(
    pid: int, centre: tuple[float, float, float], extent: tuple[float, float, float]
) -> Primitive:
    """An axis-aligned box: points on its top and its four sides."""
    c, e = np.asarray(centre, float), np.asarray(extent, float)
    u = RNG.uniform(-0.5, 0.5, (2000, 3)) * e
    face = RNG.integers(0, 5, 2000)  # 0..3: the sides ±x, ±y; 4: the top
    u[face == 0, 0], u[face == 1, 0] = e[0] / 2, -e[0] / 2
    u[face == 2, 1], u[face == 3, 1] = e[1] / 2, -e[1] / 2
    u[face == 4, 2] = e[2] / 2
    return Primitive(
        id=pid,
        model=BoxModel(center=c, rotation=np.eye(3), extent=e),
        obb=Obb(center=c, rotation=np.eye(3), extent=e),
        inlier_count=len(u),
        inliers=(c + u).astype(np.float32),
    )


def observation(
    seq: int,
    primitives: list[Primitive],
    support: list[tuple[int, int]] = (),
    T: np.ndarray | None = None,
) -> SceneObservation:
    return SceneObservation(
        seq=seq,
        stamp=float(seq),
        camera="head_rgbd",
        frame_seq=seq,
        frame_stamp=float(seq),
        T_world_camera=camera_above() if T is None else T,
        intrinsics=INTRINSICS,
        primitives=primitives,
        support_edges=[SupportEdge(supporter=a, supported=b) for a, b in support],
    )
