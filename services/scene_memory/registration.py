"""View registration (thesis A.5): a frame's camera pose, believed from odometry, refined
against the cloud registered so far before the frame is fused.

The odometry pose is the prior; the frame's cloud (downsampled) is aligned to the map's cloud
near it by point-to-plane ICP (Open3D ``registration_icp``), coarse then fine, each with Tukey's
robust loss: the part of the frame the map has not seen yet finds no partner within a few
centimetres and must not pull (with plain least squares it drags the frame along the kitchen's
counters by 0.1-0.4 m to raise the overlap, from priors 4-20 mm off). The result is
accepted only when enough of the frame found the map (fitness), the residual is small (RMSE),
the correction is plausible for odometry, and the geometry constrains all six degrees of freedom:
a blank wall fits any sliding along it, so the point-to-plane system's weakest direction must
carry a share of its strongest (Gelfand et al. 2003, "Geometrically stable sampling for the ICP
algorithm"). Otherwise the prior is kept and the reason counted.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import open3d as o3d

from schemas import BoxModel, CameraIntrinsics, CylinderModel, PlaneModel, SceneObservation
from services.common.poses import pose_difference


@dataclass(frozen=True)
class RegistrationConfig:
    #: voxels of the frame's and the map's clouds in the coarse and the fine pass, m
    coarse_voxel: float = 0.02
    fine_voxel: float = 0.01
    #: correspondence distances of the coarse and the fine pass, m
    coarse_distance: float = 0.12
    fine_distance: float = 0.04
    #: Tukey's k of the coarse and the fine pass, m: residuals beyond it weigh nothing
    #: (structured-light depth noise at 3 m is σ ≈ 1.4 cm)
    coarse_kernel: float = 0.03
    fine_kernel: float = 0.02
    iterations: int = 60
    #: accept: at least this share of the frame's points within fine_distance of the map ...
    min_fitness: float = 0.4
    #: ... with at most this RMSE, m
    max_rmse: float = 0.015
    #: ... a correction of the prior that odometry could have needed since the last
    #: registered frame (m, degrees) ...
    max_correction_m: float = 0.1
    max_correction_deg: float = 4.0
    #: ... and geometry that constrains every direction: the point-to-plane system's smallest
    #: eigenvalue over its largest (a plane: ~0; a table top with objects: ~1e-2)
    min_conditioning: float = 1e-3
    #: too few points on either side: nothing to register
    min_points: int = 200
    #: the map is cropped to the frame's bounding box grown by this, m
    margin: float = 0.3


@dataclass
class Registration:
    """``T_world_camera``: the refined pose when ``accepted``, else the prior; ``correction``:
    T_refined · T_prior⁻¹ (identity when refused); ``reason``: why it was refused."""

    T_world_camera: np.ndarray
    correction: np.ndarray
    accepted: bool
    fitness: float = 0.0
    rmse: float = math.inf
    conditioning: float = 0.0
    ms: float = 0.0
    reason: str = ""


def camera_points(
    depth: np.ndarray, K: CameraIntrinsics, depth_min: float, depth_max: float, stride: int = 2
) -> np.ndarray:
    """The frame's points in its camera's optical frame, every ``stride``-th pixel, (n, 3)."""
    z = depth[::stride, ::stride]
    v, u = np.nonzero((z > depth_min) & (z <= depth_max) & np.isfinite(z))
    d = z[v, u].astype(np.float64)
    return np.column_stack([(stride * u - K.cx) / K.fx * d, (stride * v - K.cy) / K.fy * d, d])


def _cloud(points: np.ndarray, voxel: float) -> o3d.geometry.PointCloud:
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, np.float64)))
    return pc.voxel_down_sample(voxel)


def conditioning(source: np.ndarray, normals: np.ndarray) -> float:
    """λ_min / λ_max of the point-to-plane system Σ JᵀJ, J = [(p × n)ᵀ nᵀ] (points centred, so
    rotation and translation are on one scale only after dividing the rotation part by the
    cloud's radius)."""
    p = source - source.mean(axis=0)
    radius = max(float(np.sqrt((p**2).sum(axis=1).mean())), 1e-6)
    J = np.hstack([np.cross(p, normals) / radius, normals])
    eig = np.linalg.eigvalsh(J.T @ J)
    return float(eig[0] / eig[-1]) if eig[-1] > 0 else 0.0


def register(
    points_camera: np.ndarray,
    T_prior: np.ndarray,
    map_points: np.ndarray,
    config: RegistrationConfig | None = None,
) -> Registration:
    """Refine ``T_prior`` (T_world_camera) so that the frame's points (camera frame) lie on the
    map's (world frame)."""
    c = config or RegistrationConfig()
    t0 = time.perf_counter()
    eye = np.eye(4)

    def refuse(reason: str, **scores: float) -> Registration:
        ms = (time.perf_counter() - t0) * 1e3
        return Registration(T_prior.copy(), eye, False, ms=ms, reason=reason, **scores)

    world = points_camera @ T_prior[:3, :3].T + T_prior[:3, 3]
    source = _cloud(world, c.coarse_voxel)
    if len(source.points) < c.min_points or len(map_points) < c.min_points:
        return refuse("too_few_points")
    lo, hi = source.get_min_bound() - c.margin, source.get_max_bound() + c.margin
    near = map_points[np.all((map_points >= lo) & (map_points <= hi), axis=1)]
    target = _cloud(near, c.coarse_voxel)
    if len(target.points) < c.min_points:
        return refuse("no_map_here")
    reg = o3d.pipelines.registration
    coarse_p2l = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(c.coarse_kernel))
    fine_p2l = reg.TransformationEstimationPointToPlane(reg.TukeyLoss(c.fine_kernel))
    stop = reg.ICPConvergenceCriteria(max_iteration=c.iterations)
    # one set of normals, on the coarse map (a plane sampled at 2 cm is still the plane): the
    # normals are the cost that grows with the map
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(2.5 * c.coarse_voxel, 30))
    coarse = reg.registration_icp(source, target, c.coarse_distance, eye, coarse_p2l, stop)
    # the fine pass: the frame's finer cloud, from where the coarse one ended
    source = _cloud(world, c.fine_voxel)
    fine = reg.registration_icp(
        source, target, c.fine_distance, coarse.transformation, fine_p2l, stop
    )
    correction = np.asarray(fine.transformation)
    # the geometry's conditioning, on the target normals the fine pass matched
    corr = np.asarray(fine.correspondence_set)
    cond = 0.0
    if len(corr) >= 6:
        moved = np.asarray(source.points)[corr[:, 0]] @ correction[:3, :3].T + correction[:3, 3]
        cond = conditioning(moved, np.asarray(target.normals)[corr[:, 1]])
    scores = {"fitness": float(fine.fitness), "rmse": float(fine.inlier_rmse), "conditioning": cond}
    if fine.fitness < c.min_fitness:
        return refuse("low_fitness", **scores)
    if fine.inlier_rmse > c.max_rmse:
        return refuse("high_rmse", **scores)
    if cond < c.min_conditioning:
        return refuse("degenerate", **scores)
    refined = correction @ T_prior
    moved_m, turned_deg = pose_difference(T_prior, refined)
    if moved_m > c.max_correction_m or turned_deg > c.max_correction_deg:
        return refuse("implausible", **scores)
    ms = (time.perf_counter() - t0) * 1e3
    return Registration(refined, correction, True, ms=ms, **scores)


def moved(obs: SceneObservation, T: np.ndarray) -> SceneObservation:
    """``obs`` with all its geometry moved by the rigid transform ``T`` (world → world): the
    primitives' models, boxes and inliers, support contacts, affordance poses and the camera
    pose. Perception placed the observation with the odometry's pose; T_world_odom puts it in
    the registered map."""
    R, t = T[:3, :3], T[:3, 3]

    def point(p: np.ndarray) -> np.ndarray:
        return R @ np.asarray(p, float) + t

    def model(m: Any) -> Any:
        if isinstance(m, PlaneModel):  # n·x + d = 0  →  (R n)·x' + d − (R n)·t = 0
            n = R @ m.normal
            return m.model_copy(update={"normal": n, "d": float(m.d - n @ t)})
        update: dict[str, Any] = {"center": point(m.center)}
        if isinstance(m, CylinderModel):
            update["axis"] = R @ m.axis
        if isinstance(m, BoxModel):
            update["rotation"] = R @ m.rotation
        return m.model_copy(update=update)

    def primitive(p: Any) -> Any:
        box = p.obb
        obb = box.model_copy(update={"center": point(box.center), "rotation": R @ box.rotation})
        inliers = (np.asarray(p.inliers, np.float64) @ R.T + t).astype(np.float32)
        return p.model_copy(update={"model": model(p.model), "obb": obb, "inliers": inliers})

    primitives = [primitive(p) for p in obs.primitives]
    support = [
        e.model_copy(update={"contact": point(e.contact)}) if e.contact is not None else e
        for e in obs.support_edges
    ]
    affordances = [a.model_copy(update={"poses": T @ a.poses}) for a in obs.affordances]
    return obs.model_copy(update={
        "primitives": primitives, "support_edges": support, "affordances": affordances,
        "T_world_camera": T @ obs.T_world_camera,
    })  # fmt: skip
