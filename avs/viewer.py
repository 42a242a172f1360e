"""What ``avs view`` shows, as a pure core: each AVS message becomes the rerun entities that
draw it in world coordinates (z up, metres). No Zenoh here: ``SceneLogger.entities(message)``
returns ``Entity`` values (an entity path and a rerun archetype) that the command logs, so
the mapping can be tested with schema objects alone.

Entity paths (``<camera>`` e.g. ``head_rgbd``; ``<kind>`` plane, box, cylinder, sphere)::

    world/cameras/<camera>            Transform3D (T_world_camera) + Pinhole (intrinsics)
    world/cameras/<camera>/rgb        Image h×w×3
    world/cameras/<camera>/depth      DepthImage h×w, metres
    world/cloud/<camera>              Points3D: the frame's depth back-projected (every n-th pixel)
    world/observation/primitives/<kind>   the frame's primitives, coloured by kind, labelled
    world/observation/support_graph   Arrows3D supporter centre → supported centre
    world/observation/unstable        Points3D: primitives with no support path to ρ
    world/scene/unresolved            Points3D: of those, the ones nothing was seen under
    world/scene/...                   the same for the fused scene model (labels carry occ(e))
    world/map/occupied                Boxes3D: occupied voxels, pooled to a coarser grid
    world/map/roi                     Boxes3D: the region whose unknown voxels are counted
    world/nbv/candidates              Arrows3D: each candidate view's optical axis, by utility
    world/nbv/next_view               Transform3D + Pinhole: the chosen view's frustum
    world/nbv/target                  Points3D: the point the chosen view looks at
    world/platform                    Transform3D (x, y, yaw) + world/platform/heading Arrows3D
    world/platform/ego_sphere         Points3D: ego-sphere directions coloured by saliency
    world/path                        LineStrips3D: the platform's path so far
    world/gaze/target                 Points3D: the fixation point
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import rerun as rr
from scipy.spatial.transform import Rotation

from schemas import (
    BasePose,
    CameraIntrinsics,
    CloudFrame,
    EgoSphereSnapshot,
    GazeTarget,
    NextBestView,
    OccupancySlice,
    OccupancyStats,
    RgbdFrame,
    SceneModel,
    SceneObservation,
    ViewCandidates,
)
from schemas.scene import Primitive, SceneGraph

#: the timeline every entity is logged on: when the viewer received the message (wall clock;
#: the services stamp with sim time or wall time, the arrival time orders them all)
TIMELINE = "time"
#: colour of each primitive kind (RGB)
KIND_COLOURS: dict[str, tuple[int, int, int]] = {
    "plane": (120, 140, 170),
    "box": (240, 150, 40),
    "cylinder": (60, 180, 90),
    "sphere": (200, 70, 200),
}
KINDS = tuple(KIND_COLOURS)
UNSTABLE_COLOUR = (230, 30, 30)
UNRESOLVED_COLOUR = (250, 170, 20)  # no support found, nothing seen under it either
STABLE_EDGE_COLOUR = (250, 250, 250)
UNREACHABLE_COLOUR = (90, 90, 90)
#: the ego-sphere is drawn as a sphere of this radius (m) this high above the platform (m)
EGO_SPHERE_RADIUS = 0.35
EGO_SPHERE_HEIGHT = 1.6
#: a new path point once the platform moved this far (m) or turned this much (rad)
PATH_STEP = 0.02
#: the path keeps this many points (the oldest half goes when it is full)
PATH_POINTS = 5000


@dataclass(frozen=True)
class Entity:
    """One rerun log call: ``rr.log(path, archetype, static=static)``."""

    path: str
    archetype: Any
    static: bool = False


def colormap(values: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(n,) values → (n, 3) uint8 colours, dark blue (low) through green to yellow (high)
    (viridis's anchors); NaN and inf map to the low end."""
    v = np.asarray(values, np.float64)
    finite = np.isfinite(v)
    if lo is None:
        lo = float(np.min(v[finite])) if finite.any() else 0.0
    if hi is None:
        hi = float(np.max(v[finite])) if finite.any() else 1.0
    t = np.where(finite, (v - lo) / (hi - lo) if hi > lo else 0.5, 0.0).clip(0, 1)
    anchors = np.array(
        [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], float
    )
    x = np.linspace(0, 1, len(anchors))
    return np.column_stack([np.interp(t, x, anchors[:, c]) for c in range(3)]).astype(np.uint8)


def back_project(
    depth: np.ndarray,
    intrinsics: CameraIntrinsics,
    T_world_camera: np.ndarray,
    rgb: np.ndarray | None = None,
    stride: int = 4,
    depth_max: float = 0.0,
) -> tuple[np.ndarray, np.ndarray | None]:
    """The depth image's points in the world, every ``stride``-th pixel in each direction:
    (n, 3) float32 and their (n, 3) uint8 colours (None without ``rgb``). Pixels without a
    return (0) or beyond ``depth_max`` (if > 0) are left out."""
    d = np.asarray(depth, np.float32)[::stride, ::stride]
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride]
    valid = np.isfinite(d) & (d > 0)
    if depth_max > 0:
        valid &= d <= depth_max
    z = d[valid].astype(np.float64)
    x = (u[valid] - intrinsics.cx) / intrinsics.fx * z
    y = (v[valid] - intrinsics.cy) / intrinsics.fy * z
    camera = np.column_stack([x, y, z])
    T = np.asarray(T_world_camera, np.float64)
    world = (camera @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    colours = np.asarray(rgb)[::stride, ::stride][valid] if rgb is not None else None
    return world, colours


def occupied_blocks(
    states: np.ndarray, origin: np.ndarray, voxel: float, block: float, max_blocks: int = 100_000
) -> tuple[np.ndarray, float]:
    """The occupied voxels of a slice pooled into cubes of about ``block`` m (a cube is
    occupied when any voxel in it is; coarser still while there would be more than
    ``max_blocks``): their centres (n, 3) float32 and the cube's side (m)."""
    occupied = np.asarray(states) == OccupancySlice.OCCUPIED
    factor = max(1, round(block / voxel))
    while True:
        shape = [-(-s // factor) * factor for s in occupied.shape]  # up to whole cubes
        padded = np.zeros(shape, bool)
        padded[: occupied.shape[0], : occupied.shape[1], : occupied.shape[2]] = occupied
        nx, ny, nz = (s // factor for s in shape)
        pooled = padded.reshape(nx, factor, ny, factor, nz, factor).any(axis=(1, 3, 5))
        if pooled.sum() <= max_blocks or factor >= max(occupied.shape):
            break
        factor *= 2
    side = factor * voxel
    idx = np.argwhere(pooled)
    centres = np.asarray(origin, np.float64) + (idx + 0.5) * side
    return centres.astype(np.float32), side


def _proper(R: np.ndarray) -> np.ndarray:
    """A rotation matrix from a box's axes (a left-handed set flipped to right-handed)."""
    R = np.asarray(R, np.float64)
    return R * np.array([1.0, 1.0, -1.0]) if np.linalg.det(R) < 0 else R


def _quaternions(rotations: list[np.ndarray]) -> np.ndarray:
    """(n, 4) quaternions x, y, z, w (rerun's order) of rotation matrices."""
    if not rotations:
        return np.zeros((0, 4))
    return Rotation.from_matrix(np.stack([_proper(R) for R in rotations])).as_quat()


def _z_to(axis: np.ndarray) -> np.ndarray:
    """The rotation (3×3) that turns +z onto ``axis``."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    rot, _ = Rotation.align_vectors([a], [[0.0, 0.0, 1.0]])
    return rot.as_matrix()


def _colours(kind: str, n: int) -> np.ndarray:
    return np.tile(np.array(KIND_COLOURS[kind], np.uint8), (n, 1))


def primitive_entities(prefix: str, primitives: list[Primitive]) -> list[Entity]:
    """One entity per primitive kind under ``prefix/primitives``: planes and boxes as their
    oriented boxes, cylinders as cylinders, spheres as spheres; labelled ``kind id``. A kind
    without primitives is logged empty (it clears what an earlier message drew)."""
    by_kind: dict[str, list[Primitive]] = {k: [] for k in KINDS}
    for p in primitives:
        by_kind[p.kind].append(p)
    out = []
    for kind, group in by_kind.items():
        labels = [f"{kind} {p.id}" for p in group]
        colours = _colours(kind, len(group))
        if kind == "cylinder":
            shape: Any = rr.Cylinders3D(
                centers=np.array([p.model.center for p in group]).reshape(-1, 3),
                lengths=[p.model.height for p in group],
                radii=[p.model.radius for p in group],
                quaternions=_quaternions([_z_to(p.model.axis) for p in group]),
                colors=colours,
                labels=labels,
            )
        elif kind == "sphere":
            shape = rr.Ellipsoids3D(
                centers=np.array([p.model.center for p in group]).reshape(-1, 3),
                half_sizes=np.array([[p.model.radius] * 3 for p in group]).reshape(-1, 3),
                colors=colours,
                labels=labels,
            )
        else:  # plane, box: the oriented bounding box (a plane's is thin)
            shape = rr.Boxes3D(
                centers=np.array([p.obb.center for p in group]).reshape(-1, 3),
                half_sizes=np.array([np.maximum(p.obb.extent, 1e-3) / 2 for p in group]).reshape(
                    -1, 3
                ),
                quaternions=_quaternions([p.obb.rotation for p in group]),
                colors=colours,
                labels=labels,
            )
        out.append(Entity(f"{prefix}/primitives/{kind}", shape))
    return out


def support_graph_entities(prefix: str, graph: SceneGraph, with_occ: bool) -> list[Entity]:
    """The support graph as arrows from each supporter's centre to its supported primitive's
    (red into an unstable one; labelled with occ(e) in the fused model), and the unstable
    primitives (no support path to ρ) as red points at their centres, those whose support
    is unresolved (the fused model's: nothing seen under them) amber."""
    centre = {p.id: np.asarray(p.obb.center, np.float64) for p in graph.primitives}
    unstable = set(graph.unstable_ids)
    edges = graph.support_edges
    origins = np.array([centre[e.supporter] for e in edges]).reshape(-1, 3)
    tips = np.array([centre[e.supported] for e in edges]).reshape(-1, 3)
    colours = np.array(
        [UNSTABLE_COLOUR if e.supported in unstable else STABLE_EDGE_COLOUR for e in edges],
        np.uint8,
    ).reshape(-1, 3)
    labels = [f"occ {e.occ}" for e in edges] if with_occ else None
    ids, unresolved = sorted(unstable), sorted(graph.unresolved_ids)
    return [
        Entity(
            f"{prefix}/support_graph",
            rr.Arrows3D(
                origins=origins, vectors=tips - origins, colors=colours, labels=labels, radii=0.004
            ),
        ),
        _marks(f"{prefix}/unstable", [centre[i] for i in ids], UNSTABLE_COLOUR,
               [f"unstable {i}" for i in ids]),
        _marks(f"{prefix}/unresolved", [centre[i] for i in unresolved], UNRESOLVED_COLOUR,
               [f"unresolved {i}" for i in unresolved]),
    ]  # fmt: skip


def _marks(path: str, at: list, colour: tuple, labels: list[str]) -> Entity:
    return Entity(
        path,
        rr.Points3D(
            np.array(at).reshape(-1, 3),
            colors=np.tile(np.array(colour, np.uint8), (len(at), 1)),
            labels=labels,
            radii=0.03,
        ),
    )


def _camera(path: str, T: np.ndarray, intrinsics: CameraIntrinsics, plane: float) -> list[Entity]:
    T = np.asarray(T, np.float64)
    return [
        Entity(path, rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3])),
        Entity(
            path,
            rr.Pinhole(
                image_from_camera=intrinsics.K(),
                resolution=[intrinsics.width, intrinsics.height],
                camera_xyz=rr.ViewCoordinates.RDF,  # optical: x right, y down, z forward
                image_plane_distance=plane,
            ),
        ),
    ]


@dataclass
class SceneLogger:
    """Turns AVS messages into rerun entities, keeping what a drawing needs from earlier
    messages (the platform's path, the last intrinsics for the chosen view's frustum)."""

    cloud_stride: int = 4
    map_block: float = 0.04
    path: list[np.ndarray] = field(default_factory=list)  # (x, y, yaw) of the path so far
    intrinsics: CameraIntrinsics | None = None

    @staticmethod
    def setup() -> list[Entity]:
        """Static entities: the world is z up."""
        return [Entity("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)]

    def entities(self, message: Any) -> list[Entity]:
        """The entities that draw ``message`` ([] for a message the viewer does not show)."""
        handler = self._HANDLERS.get(type(message))
        return handler(self, message) if handler is not None else []

    def frame(self, m: RgbdFrame) -> list[Entity]:
        """The camera (pose, frustum) with its images, and the depth's points in the world."""
        self.intrinsics = m.intrinsics
        path = f"world/cameras/{m.camera}"
        out = _camera(path, m.T_world_camera, m.intrinsics, 0.2)
        if m.rgb is not None:
            out.append(Entity(f"{path}/rgb", rr.Image(m.rgb)))
        if m.depth is not None:
            out.append(Entity(f"{path}/depth", rr.DepthImage(m.depth, meter=1.0)))
            points, colours = back_project(
                m.depth, m.intrinsics, m.T_world_camera, m.rgb, self.cloud_stride, m.depth_max
            )
            out.append(
                Entity(f"world/cloud/{m.camera}", rr.Points3D(points, colors=colours, radii=0.004))
            )
        return out

    def cloud_frame(self, m: CloudFrame) -> list[Entity]:
        """The scene memory's registered cloud (pc / pc+sg fusion)."""
        return [
            Entity(f"world/cloud/{m.camera}", rr.Points3D(m.points, colors=m.colours, radii=0.004))
        ]

    def observation(self, m: SceneObservation) -> list[Entity]:
        return primitive_entities("world/observation", m.primitives) + support_graph_entities(
            "world/observation", m, with_occ=False
        )

    def scene(self, m: SceneModel) -> list[Entity]:
        return primitive_entities("world/scene", m.primitives) + support_graph_entities(
            "world/scene", m, with_occ=True
        )

    def occupancy(self, m: OccupancySlice) -> list[Entity]:
        """Occupied voxels, pooled to cubes of about ``map_block`` m, coloured by height."""
        centres, side = occupied_blocks(m.states, m.origin, m.voxel_size, self.map_block)
        return [
            Entity(
                "world/map/occupied",
                rr.Boxes3D(
                    centers=centres,
                    half_sizes=np.full((len(centres), 3), side / 2, np.float32),
                    colors=colormap(centres[:, 2]),
                    fill_mode="solid",
                ),
            )
        ]

    def roi(self, m: OccupancyStats) -> list[Entity]:
        lo, hi = np.asarray(m.box_min), np.asarray(m.box_max)
        return [
            Entity(
                "world/map/roi",
                rr.Boxes3D(
                    centers=[(lo + hi) / 2],
                    half_sizes=[(hi - lo) / 2],
                    colors=[(255, 220, 0)],
                    labels=[f"roi: {m.unknown} unknown voxels"],
                ),
            )
        ]

    def candidates(self, m: ViewCandidates) -> list[Entity]:
        """Each candidate's optical axis (0.15 m) from its camera position, coloured by u(v)
        (unreachable ones grey)."""
        views = np.asarray(m.views)
        reachable = np.asarray(m.reachable, bool) & np.isfinite(m.utility)
        colours = np.tile(np.array(UNREACHABLE_COLOUR, np.uint8), (len(views), 1))
        if reachable.any():
            colours[reachable] = colormap(np.asarray(m.utility)[reachable])
        return [
            Entity(
                "world/nbv/candidates",
                rr.Arrows3D(
                    origins=views[:, :3, 3],
                    vectors=0.15 * views[:, :3, 2],
                    colors=colours,
                    radii=0.006,
                ),
            )
        ]

    def next_view(self, m: NextBestView) -> list[Entity]:
        """The chosen view's frustum (the last frame's intrinsics, or a Carmine's) and the point
        it looks at."""
        if m.terminate:
            return []
        intrinsics = self.intrinsics or CameraIntrinsics.from_fov(640, 480, 45.0)
        label = f"step {m.step}: u {m.utility:.3g}, IG {m.information_gain:.3g}"
        return [
            *_camera("world/nbv/next_view", m.view, intrinsics, 0.4),
            Entity(
                "world/nbv/target",
                rr.Points3D([m.target], colors=[(255, 60, 200)], radii=0.02, labels=[label]),
            ),
            *self.gaze_point(np.asarray(m.target), "nbv"),
        ]

    def gaze_point(self, point: np.ndarray, source: str) -> list[Entity]:
        marker = rr.Points3D(
            [point], colors=[(0, 220, 255)], radii=0.025, labels=[f"gaze: {source}"]
        )
        return [Entity("world/gaze/target", marker)]

    def gaze_target(self, m: GazeTarget) -> list[Entity]:
        return self.gaze_point(np.asarray(m.point), m.source)

    def base(self, m: BasePose) -> list[Entity]:
        """The platform's pose, and its path when it moved ``PATH_STEP`` since the last
        point."""
        pose = np.array([m.x, m.y, m.yaw])
        out = [
            Entity(
                "world/platform",
                rr.Transform3D(
                    translation=[m.x, m.y, 0.0],
                    rotation_axis_angle=rr.RotationAxisAngle(axis=[0, 0, 1], radians=m.yaw),
                ),
            ),
        ]
        if not self.path:
            out.append(
                Entity(
                    "world/platform/heading",
                    rr.Arrows3D(
                        origins=[[0, 0, 0.05]], vectors=[[0.4, 0, 0]], colors=[(255, 255, 255)]
                    ),
                ),
            )
        last = self.path[-1] if self.path else None
        turned = last is not None and abs(np.angle(np.exp(1j * (pose[2] - last[2])))) >= 0.1
        if last is None or np.hypot(*(pose[:2] - last[:2])) >= PATH_STEP or turned:
            self.path.append(pose)
            if len(self.path) > PATH_POINTS:
                del self.path[: PATH_POINTS // 2]
            xy = np.array(self.path)[:, :2]
            strip = np.column_stack([xy, np.full(len(xy), 0.01)])
            out.append(
                Entity(
                    "world/path", rr.LineStrips3D([strip], colors=[(255, 255, 255)], radii=0.008)
                )
            )
        return out

    def ego_sphere(self, m: EgoSphereSnapshot) -> list[Entity]:
        """The ego-sphere's directions on a sphere above the platform, coloured by saliency
        s_j (Eq. 5.1); the winner larger."""
        points = np.asarray(m.directions, np.float32) * EGO_SPHERE_RADIUS + np.array(
            [0, 0, EGO_SPHERE_HEIGHT], np.float32
        )
        radii = np.full(len(points), 0.006, np.float32)
        if m.winner >= 0:
            radii[m.winner] = 0.03
        colours = colormap(m.saliency, lo=0.0)
        return [
            Entity("world/platform/ego_sphere", rr.Points3D(points, colors=colours, radii=radii))
        ]

    _HANDLERS: ClassVar[dict[type, Any]] = {
        RgbdFrame: frame,
        CloudFrame: cloud_frame,
        SceneObservation: observation,
        SceneModel: scene,
        OccupancySlice: occupancy,
        OccupancyStats: roi,
        ViewCandidates: candidates,
        NextBestView: next_view,
        GazeTarget: gaze_target,
        BasePose: base,
        EgoSphereSnapshot: ego_sphere,
    }


def log_entities(recording: rr.RecordingStream, entities: list[Entity], stamp: float) -> None:
    """Log ``entities`` on ``recording`` at ``stamp`` (s since the epoch) on ``TIMELINE``."""
    recording.set_time(TIMELINE, timestamp=stamp)
    for e in entities:
        recording.log(e.path, e.archetype, static=e.static)
