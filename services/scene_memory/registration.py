"""View registration (thesis A.5): a frame's camera pose, believed from odometry, refined
against the cloud registered so far before the frame is fused.

The odometry pose is the prior; the frame's cloud (averaged on a voxel grid) is aligned to the
map by point-to-plane ICP (``icp``: against the planes of a voxel map that every integrated
frame adds to, ``RegistrationMap``), at three resolutions coarse to fine, each with Tukey's
robust loss: the part of the frame the map has not seen yet finds no partner within a few
centimetres and must not pull (with plain least squares it drags the frame along the kitchen's
counters by 0.1-0.4 m to raise the overlap, from priors 4-20 mm off). The result is
accepted only when enough of the frame found the map (fitness), the residual is small (RMSE),
the correction is plausible for odometry, and the geometry constrains every degree of freedom
solved for: a blank wall fits any sliding along it, so the point-to-plane system's weakest
direction must carry a share of its strongest (Gelfand et al. 2003, "Geometrically stable
sampling for the ICP algorithm"). Otherwise the prior is kept and the reason counted.

``dof``: a wheeled platform's odometry drifts in x, y and yaw only; the head camera's height,
roll and pitch come from joint encoders and kinematics. ``"planar"`` solves for that drift
alone: the correction T_world_odom is a yaw about the world's vertical through its origin and
a shift in the ground plane (together any planar rigid motion, wherever the turn pivots), the
degeneracy check is on that 3×3 system, and a frame whose height or tilt disagrees with the map
by more than the kinematics could (the full six-unknown step from the planar fit wants more
than ``max_off_plane_m`` / ``max_off_plane_deg``) is refused, not slid sideways to make up for
it. ``"full"`` solves all six (a hand-held camera, or a platform that is not level).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from schemas import BoxModel, CameraIntrinsics, CylinderModel, PlaneModel, SceneObservation
from services.common.poses import pose_difference
from services.scene_memory.correction_filter import OdometryNoise, RegistrationNoise
from services.scene_memory.icp import FULL, PLANAR, candidates, icp, residuals
from services.scene_memory.voxel_map import VoxelMap, means, summarise

#: ``constraint``: a normal whose |z| is at least this is a level surface's (about 25°)
LEVEL = 0.9


@dataclass(frozen=True)
class Pass:
    """One resolution of the coarse-to-fine ICP."""

    #: the map's voxel, m: a point is matched to its own voxel or one around its nearest corner
    map_voxel: float
    #: the frame's cloud is averaged on this voxel, m, and thinned to at most ``points``
    source_voxel: float
    points: int
    #: a match farther than this from its voxel's mean is none, m
    distance: float
    #: Tukey's k, m: residuals beyond it weigh nothing (structured-light depth noise at 3 m is
    #: σ ≈ 1.4 cm)
    kernel: float
    #: a map voxel whose 3×3×3 neighbourhood's points lie farther than this (RMS, m) from
    #: their plane has none: an edge or a corner, not a surface (on 19 kitchen views the
    #: registered poses' 90th percentile error fell from 3.3 to 2.6 mm). Above the depth noise
    #: the finest level sees most (σ ≈ 1 cm at 2.5 m; farther points weigh little anyway)
    thickness: float


@dataclass(frozen=True)
class RegistrationConfig:
    #: the unknowns: "planar" (a ground platform's odometry drift: x, y, yaw about the world's
    #: z) or "full" (six)
    dof: Literal["planar", "full"] = "planar"
    #: coarse to fine: 8 cm voxels catch a prior 16 cm off (3° at 3 m), 1.5 cm ones settle it
    passes: tuple[Pass, ...] = (
        Pass(map_voxel=0.08, source_voxel=0.04, points=1500, distance=0.16, kernel=0.04,
             thickness=0.03),
        Pass(map_voxel=0.03, source_voxel=0.02, points=3000, distance=0.06, kernel=0.02,
             thickness=0.012),
        Pass(map_voxel=0.015, source_voxel=0.02, points=5000, distance=0.03, kernel=0.015,
             thickness=0.01),
    )  # fmt: skip
    #: Gauss-Newton steps per pass, and the step (m, or rad × 1 m) that ends a pass
    iterations: int = 30
    tolerance: float = 1e-4
    #: accept: at least this share of the frame's points on the map (within about 3 cm) ...
    min_fitness: float = 0.3
    #: ... with at most this point-to-plane RMSE, m
    max_rmse: float = 0.015
    #: ... a correction of the prior that odometry could have needed since the last
    #: registered frame (m, degrees) ...
    max_correction_m: float = 0.1
    max_correction_deg: float = 4.0
    #: ... and geometry that constrains every direction: the point-to-plane system's smallest
    #: eigenvalue over its largest (a plane: ~0; a table top with objects: ~1e-2)
    min_conditioning: float = 1e-3
    #: ... and at least this λ_min / n (``constraint``): enough of the frame on upright
    #: surfaces that hold the weakest direction (a round table with a vase at its centre,
    #: seen from its far side: 0; tables seen from opposite sides: 3e-4 to 7e-3)
    min_strength: float = 2e-4
    #: "planar": refuse a frame whose height (m) or tilt (degrees) the full point-to-plane step
    #: from the planar fit would change by more than this: no head kinematics is that far off
    #: on a level platform (a ramp, a lifted wheel: "full"), and a planar fit of such a frame
    #: is not its pose (a synthetic room rolled 3°: 4 cm sideways). Not tighter: on a
    #: hand-held Kinect v1 (redkitchen-a, its reference poses as the "kinematics") the step
    #: wants up to 4.8 cm and 2.5°, and each refused frame leaves the map where the next
    #: frames need it (at 3 cm and 1.5°, 25 of 31 were refused)
    max_off_plane_m: float = 0.1
    max_off_plane_deg: float = 5.0
    #: each point weighs 1/σ(z)² of its depth's axial noise, σ(z) = sigma0 + sigma2·(z − 0.4)²
    #: (Nguyen et al. 2012, the sim's structured-light model), relative to sigma_ref
    sigma0: float = 0.0012
    sigma2: float = 0.0019
    sigma_ref: float = 0.003
    #: too few points on either side: nothing to register
    min_points: int = 200
    #: the correction is a filter's state (``correction_filter``): each accepted registration
    #: is weighed against the odometry's error since the last one (its motion model) and the
    #: registration's own; None: each is taken as it comes (the thesis's A.5). Not the
    #: default: where the odometry drifts more than its model says and the camera barely
    #: moves (a platform drifting 1.2 cm a view while the head pans), a filter trusts it too
    #: much; where registration errs by centimetres (a Kinect v1, redkitchen-a) it helps
    odometry_noise: OdometryNoise | None = None
    registration_noise: RegistrationNoise = field(default_factory=RegistrationNoise)
    #: ... and refused when the odometry's uncertainty and the registration's cannot explain
    #: it: its d² (``CorrectionFilter.mahalanobis``) beyond the χ² 99.9 % quantile of the
    #: unknowns (3: 16.3, 6: 22.5)
    max_mahalanobis: dict[str, float] = field(
        default_factory=lambda: {"planar": 16.27, "full": 22.46}
    )


class RegistrationMap:
    """The registered cloud at each pass's resolution (``VoxelMap``): what frames are
    registered against, updated as they are integrated."""

    def __init__(self, config: RegistrationConfig | None = None) -> None:
        c = config or RegistrationConfig()
        self.levels = [VoxelMap(p.map_voxel) for p in c.passes]

    @classmethod
    def of(
        cls, points: np.ndarray, config: RegistrationConfig | None = None,
        eyes: np.ndarray | None = None,
    ) -> RegistrationMap:  # fmt: skip
        out = cls(config)
        out.add(points, eyes)
        return out

    def add(self, points_world: np.ndarray, eyes: np.ndarray | None = None) -> None:
        """Add points (world frame); ``eyes``: the camera they were seen from (3,) or each
        one's (n, 3), so that a frame is not matched to the far side of what it sees."""
        for level in self.levels:
            level.add(points_world, eyes)

    def __len__(self) -> int:
        return len(self.levels[-1])


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
    #: "planar": the height (m) and tilt (degrees) the full step from the planar fit wants
    off_plane_m: float = 0.0
    off_plane_deg: float = 0.0
    #: λ_min / n of the point-to-plane system (``constraint``)
    strength: float = 0.0
    #: refined by the level surfaces' outlines (``hypotheses.outlined``), and how much of the
    #: outline agreed (Tukey weight)
    outlined: bool = False
    outline_weight: float = 0.0


def camera_points(
    depth: np.ndarray, K: CameraIntrinsics, depth_min: float, depth_max: float, stride: int = 2
) -> np.ndarray:
    """The frame's points in its camera's optical frame, every ``stride``-th pixel, (n, 3)."""
    z = depth[::stride, ::stride]
    v, u = np.nonzero((z > depth_min) & (z <= depth_max) & np.isfinite(z))
    d = z[v, u].astype(np.float64)
    return np.column_stack([(stride * u - K.cx) / K.fx * d, (stride * v - K.cy) / K.fy * d, d])


def conditioning(source: np.ndarray, normals: np.ndarray, planar: bool = False) -> float:
    """λ_min / λ_max of the point-to-plane system Σ JᵀJ (``constraint``)."""
    return constraint(source, normals, planar)[0]


def constraint(
    source: np.ndarray, normals: np.ndarray, planar: bool = False
) -> tuple[float, float]:
    """The point-to-plane system Σ JᵀJ, J = [(p × n)ᵀ nᵀ] (points centred, so rotation and
    translation are on one scale only after dividing the rotation part by the cloud's radius);
    ``planar``: its 3×3 part in (yaw, x, y), J = [(p × n)_z nx ny], the radius the horizontal
    one (a level floor constrains none of them). Returns λ_min / λ_max (Gelfand et al. 2003)
    and λ_min / n, the share of the points that holds the weakest direction (``planar``: of
    the rows of upright surfaces only). A ratio is blind to scale: where nearly every point
    lies on a level surface, the depth noise's tilt of their normals alone makes the system
    look round (a round table seen from its far side: 19 of 4361 points on anything upright,
    λ_min / λ_max 0.5, λ_min / n 0)."""
    p = source - source.mean(axis=0)
    if planar:
        radius = max(float(np.sqrt((p[:, :2] ** 2).sum(axis=1).mean())), 1e-6)
        turn = p[:, 0] * normals[:, 1] - p[:, 1] * normals[:, 0]
        J = np.column_stack([turn / radius, normals[:, 0], normals[:, 1]])
    else:
        radius = max(float(np.sqrt((p**2).sum(axis=1).mean())), 1e-6)
        J = np.hstack([np.cross(p, normals) / radius, normals])
    eig = np.linalg.eigvalsh(J.T @ J)
    if eig[-1] <= 0:
        return 0.0, 0.0
    # the share: of the rows of surfaces that can hold a shift or turn in the plane solved
    # for, not of the noise on level ones (planar: normals more than ~25° off the vertical)
    upright = np.abs(normals[:, 2]) < LEVEL if planar else slice(None)
    held = np.linalg.eigvalsh(J[upright].T @ J[upright])[0] if planar else eig[0]
    return float(eig[0] / eig[-1]), float(max(held, 0.0) / len(J))


def depth_weights(z: np.ndarray, c: RegistrationConfig) -> np.ndarray:
    """Each point's weight, (σ_ref / σ(z))², σ(z) = sigma0 + sigma2·(z − 0.4)² the axial noise
    of a structured-light depth at z (Nguyen et al. 2012)."""
    return (c.sigma_ref / (c.sigma0 + c.sigma2 * np.maximum(z - 0.4, 0.0) ** 2)) ** 2


def _sources(points_camera: np.ndarray, c: RegistrationConfig) -> list[np.ndarray]:
    """Per pass, the frame's cloud averaged on the pass's source voxel, every k-th voxel to
    the pass's ``points`` (passes with one source voxel share the averaging)."""
    averaged: dict[float, np.ndarray] = {}
    out = []
    for p in c.passes:
        if p.source_voxel not in averaged:
            index, stats = summarise(points_camera, p.source_voxel)
            averaged[p.source_voxel] = means(index, stats, p.source_voxel)
        centres = averaged[p.source_voxel]
        out.append(np.ascontiguousarray(centres[:: -(-len(centres) // p.points)]))
    return out


def refused(T_prior: np.ndarray, reason: str, ms: float, **scores: float) -> Registration:
    """A refusal for ``reason``: the prior kept, no correction."""
    return Registration(T_prior.copy(), np.eye(4), False, ms=ms, reason=reason, **scores)


def register(
    points_camera: np.ndarray,
    T_prior: np.ndarray,
    target: RegistrationMap | np.ndarray,
    config: RegistrationConfig | None = None,
) -> Registration:
    """Refine ``T_prior`` (T_world_camera) so that the frame's points (camera frame) lie on the
    map (a ``RegistrationMap``, or the map's points in the world frame)."""
    c = config or RegistrationConfig()
    t0 = time.perf_counter()

    def refuse(reason: str, **scores: float) -> Registration:
        return refused(T_prior, reason, (time.perf_counter() - t0) * 1e3, **scores)

    if not isinstance(target, RegistrationMap):
        target = RegistrationMap.of(np.asarray(target, np.float64), c)
    points_camera = np.ascontiguousarray(points_camera, np.float64)
    R, t = T_prior[:3, :3], T_prior[:3, 3]
    camera = np.ascontiguousarray(t, np.float64)  # for icp's check of sides
    cams = _sources(points_camera, c)
    sources = [np.ascontiguousarray(q @ R.T + t) for q in cams]
    weights = [depth_weights(q[:, 2], c) for q in cams]
    if len(sources[-1]) < c.min_points or len(target) < c.min_points:
        return refuse("too_few_points")
    # each pass's points keep their matches' candidates from one ICP step to the next (and
    # from the check that the map is there, and into the final residuals)
    caches = [candidates(len(s)) for s in sources]
    first, level = c.passes[0], target.levels[0]
    near, _, _ = residuals(
        sources[0], *level.arrays(), first.thickness, np.eye(4), first.distance, caches[0], camera
    )
    if near.sum() < min(c.min_points, len(near) // 2):
        return refuse("no_map_here")
    correction = np.eye(4)
    planar = c.dof == "planar"
    free = PLANAR if planar else FULL
    passes = zip(c.passes, target.levels, sources, weights, caches, strict=True)
    for p, level, source, w, cache in passes:
        correction, _ = icp(source, *level.arrays(), p.thickness, correction, p.distance, p.kernel,
                            c.iterations, c.tolerance, w, cache, free, camera)  # fmt: skip
    matched, r, normals = residuals(
        source, *level.arrays(), p.thickness, correction, p.distance, cache, camera
    )
    # the overlap: the share of the frame that lies on the map within the second finest
    # pass's reach (a point finds its candidates within about one voxel, 3 cm; the finest
    # pass's 1.5 cm would count a surface the depth noise blurs as half off the map)
    k = max(len(c.passes) - 2, 0)
    near, _, _ = residuals(sources[k], *target.levels[k].arrays(), c.passes[k].thickness,
                           correction, c.passes[k].distance, caches[k], camera)  # fmt: skip
    fitness = float(near.mean())
    rmse = float(np.sqrt(np.mean(r[matched] ** 2))) if matched.any() else math.inf
    cond = strength = 0.0
    if matched.sum() >= 6:
        moved = source[matched] @ correction[:3, :3].T + correction[:3, 3]
        cond, strength = constraint(moved, normals[matched], planar)
    scores = {"fitness": fitness, "rmse": rmse, "conditioning": cond, "strength": strength}
    if planar:
        scores["off_plane_m"], scores["off_plane_deg"] = off_plane(
            sources[0], target.levels[0], c.passes[0], correction, correction @ T_prior,
            weights[0], caches[0], c, camera
        )  # fmt: skip
    if fitness < c.min_fitness:
        return refuse("low_fitness", **scores)
    if rmse > c.max_rmse:
        return refuse("high_rmse", **scores)
    if cond < c.min_conditioning or strength < c.min_strength:
        return refuse("degenerate", **scores)
    if planar and (
        scores["off_plane_m"] > c.max_off_plane_m or scores["off_plane_deg"] > c.max_off_plane_deg
    ):
        return refuse("off_plane", **scores)
    refined = correction @ T_prior
    moved_m, turned_deg = pose_difference(T_prior, refined)
    if moved_m > c.max_correction_m or turned_deg > c.max_correction_deg:
        return refuse("implausible", **scores)
    ms = (time.perf_counter() - t0) * 1e3
    return Registration(refined, correction, True, ms=ms, **scores)


def off_plane(
    source: np.ndarray, level: VoxelMap, p: Pass, correction: np.ndarray, T_camera: np.ndarray,
    weights: np.ndarray, cache: tuple, c: RegistrationConfig, eye: np.ndarray,
) -> tuple[float, float]:  # fmt: skip
    """What a planar fit leaves: from ``correction``, a few full (six-unknown) Gauss-Newton
    steps on the coarsest pass with its whole reach as the kernel (a height 4 cm off is past
    the finer passes' kernels: their matches on the floor weigh nothing and show nothing); how
    far they move the camera (``T_camera``) vertically (m) and tilt it (degrees)."""
    T, _ = icp(source, *level.arrays(), p.thickness, correction, p.distance, p.distance,
               3, c.tolerance, weights, cache, FULL, eye)  # fmt: skip
    step = T @ np.linalg.inv(correction)
    centre = T_camera[:3, 3]
    height = abs(float((step[:3, :3] @ centre + step[:3, 3])[2] - centre[2]))
    tilt = math.degrees(math.acos(min(1.0, max(-1.0, float(step[2, 2])))))
    return height, tilt


def warm_up() -> None:
    """Register a small synthetic frame once: loads the compiled kernels (or compiles them,
    ~15 s on the first run on a machine) before the first real frame arrives."""
    g = np.linspace(0.0, 0.5, 51)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    zero = np.zeros_like(u)
    corner = np.vstack([np.column_stack(c) for c in ((u, v, zero), (u, zero, v), (zero, u, v))])
    T = np.eye(4)
    T[:3, 3] = (0.01, -0.01, 0.01)
    register(corner, T, corner)


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
