"""Which way is up in a recording whose world frame is its own (7-Scenes: the first camera's):
from its dominant horizontal surfaces. A kitchen, an office, a table top: the floor and the
table tops are large planes, and they are level.

``estimate_up`` back-projects a few frames into the dataset's world (their poses), finds its
largest planes (Open3D's RANSAC, one after another), keeps those within ``max_tilt`` of a first
guess of up (the cameras' −y axes: a hand-held or head camera is held about level), and takes
up as their normals' mean weighted by their inliers. The floor is the lowest of the level planes
that holds a share of the points (else the lowest points). ``T_up`` turns the world so that up
is +z, and moves it so that the floor is at z = 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import open3d as o3d


@dataclass(frozen=True)
class Up:
    T_up: np.ndarray  # 4×4: dataset world → z up, floor at z = 0
    up: np.ndarray  # the dataset world's up (unit)
    floor: float  # the floor's height along ``up`` in the dataset's world, m
    planes: list[tuple[float, int]]  # the level planes: (height above the floor, inliers)
    detail: str  # how it was found, in words

    def to_json(self) -> dict:
        return {"T_up": np.round(self.T_up, 6).tolist(), "up": np.round(self.up, 6).tolist(),
                "floor_m": round(self.floor, 4),
                "level_planes": [{"height_m": h, "points": k} for h, k in self.planes],
                "detail": self.detail}  # fmt: skip


def back_project(depth: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                 T_world_camera: np.ndarray, step: int = 4) -> np.ndarray:  # fmt: skip
    """Every ``step``-th pixel's point in the world (holes left out)."""
    d = depth[::step, ::step]
    v, u = np.nonzero(d > 0)
    z = d[v, u].astype(np.float64)
    x = (u * step - cx) * z / fx
    y = (v * step - cy) * z / fy
    p = np.column_stack([x, y, z])
    return p @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """The smallest rotation taking ``up`` to +z."""
    a = up / np.linalg.norm(up)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1 + c)


def estimate_up(
    clouds: list[np.ndarray],
    poses: list[np.ndarray],
    max_tilt_deg: float = 30.0,
    planes: int = 8,
    distance: float = 0.02,
    floor_share: float = 0.03,
    seed: int = 0,
) -> Up:
    """Up and the floor from world points ``clouds`` seen by cameras at ``poses``."""
    guess = -np.mean([T[:3, 1] for T in poses], axis=0)
    guess /= np.linalg.norm(guess)
    points = np.concatenate(clouds)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd = pcd.voxel_down_sample(0.03)
    n_all = len(pcd.points)
    o3d.utility.random.seed(seed)
    found: list[tuple[np.ndarray, float, int]] = []  # (unit normal toward up, offset, inliers)
    rest = pcd
    for _ in range(planes):
        if len(rest.points) < 200:
            break
        (a, b, c, d), inliers = rest.segment_plane(distance, 3, 500)
        n = np.array([a, b, c])
        norm = np.linalg.norm(n)
        n, d = n / norm, d / norm
        if n @ guess < 0:
            n, d = -n, -d
        found.append((n, d, len(inliers)))
        rest = rest.select_by_index(inliers, invert=True)
    cos_tilt = math.cos(math.radians(max_tilt_deg))
    level = [(n, d, k) for n, d, k in found if n @ guess >= cos_tilt]
    if not level:
        up = guess
        detail = f"no level plane among {len(found)}: up from the cameras' −y axes"
    else:
        w = np.array([k for _, _, k in level], float)
        up = np.sum([n * k for n, _, k in level], axis=0) / w.sum()
        up /= np.linalg.norm(up)
        tilt = math.degrees(math.acos(min(1.0, float(up @ guess))))
        detail = (f"{len(level)} level planes of {len(found)} ({int(w.sum())} of {n_all} points), "
                  f"{tilt:.1f}° from the cameras' −y axes")  # fmt: skip
    # heights of the level planes along up (a point p on n·p + d = 0 has n·p = −d), each
    # refined as the median height of every point (not the 3 cm sample) within ``distance``
    along = points @ up
    heights = []
    for _, d, k in level:
        near = np.abs(along + d) < distance
        heights.append((float(np.median(along[near])) if near.any() else -d, k))
    heights.sort()
    floors = [h for h, k in heights if k >= floor_share * n_all]
    if floors:
        floor = floors[0]
        detail += f"; the floor: the lowest level plane ({floor:.3f} m along up)"
    else:
        floor = float(np.percentile(points @ up, 1))
        detail += "; no level plane large enough for a floor: the lowest 1 % of the points"
    R = rotation_to_z(up)
    T = np.eye(4)
    T[:3, :3] = R
    T[2, 3] = -floor
    return Up(T, up, floor, [(round(h - floor, 3), k) for h, k in heights], detail)


#: ° within which the dataset's own z counts as up already (its frame is kept, floor and all)
Z_UP_DEG = 5.0


def level_frame(frames, samples: int = 8) -> Up:
    """``estimate_up`` on ``samples`` frames spread over what ``frames`` (a DatasetFrames)
    plays, with their poses as the dataset gives them. Where the dataset's z is up already
    (within ``Z_UP_DEG``: a robot's base_link, a TUM groundtruth aligned to gravity) its frame
    is kept as it is: the floor may not be in view to move it to."""
    import dataclasses

    chosen = frames.indices()
    picks = chosen[:: max(1, len(chosen) // samples)][:samples]
    clouds, poses = [], []
    kept, frames.T_up = frames.T_up, np.eye(4)
    try:
        for i in picks:
            f = frames.frame(i, 0)
            k = f.intrinsics
            clouds.append(back_project(f.depth, k.fx, k.fy, k.cx, k.cy, f.T_world_camera))
            poses.append(f.T_world_camera)
    finally:
        frames.T_up = kept
    up = estimate_up(clouds, poses)
    tilt = math.degrees(math.acos(min(1.0, abs(float(up.up[2])))))
    if up.up[2] > 0 and tilt < Z_UP_DEG:
        return dataclasses.replace(
            up, T_up=np.eye(4), floor=0.0,
            planes=[(round(h + up.floor, 3), k) for h, k in up.planes],
            detail=f"the dataset's z is up already ({tilt:.1f}° from the level planes' normal): "
            f"its frame kept; {up.detail.split('; ')[0]}",
        )  # fmt: skip
    return up
