"""The semantic scene: geometric primitives, spatial and support graphs, affordances (Ch. 3)."""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, model_validator

from schemas.arrays import Array
from schemas.base import Model, Stamped
from schemas.sensors import CameraIntrinsics
from schemas.types import Direction, Finite, Pose, Poses, Vec3

#: Most inlier points a primitive carries on the wire (downsampled for transport).
MAX_INLIERS = 2000

PrimitiveKind = Literal["plane", "cylinder", "sphere", "box"]
AffordanceKind = Literal["grasp", "lift", "push", "support", "lean", "hold"]


class Obb(Model):
    """Oriented bounding box: centre, rotation (columns = box axes in the world), full side
    lengths."""

    center: Vec3
    rotation: Annotated[np.ndarray, Array("float64", (3, 3)), Finite()]
    extent: Annotated[np.ndarray, Array("float64", (3,)), Finite()]


class PlaneModel(Model):
    """n·x + d = 0, n a unit normal."""

    kind: Literal["plane"] = "plane"
    normal: Direction
    d: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of points (n, 3) to the surface."""
        return np.abs(np.asarray(points) @ self.normal + self.d)


class CylinderModel(Model):
    """A finite cylinder: centre point on the axis, unit axis, radius, height along the axis."""

    kind: Literal["cylinder"] = "cylinder"
    center: Vec3
    axis: Direction
    radius: float = Field(gt=0)
    height: float = Field(ge=0)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of points (n, 3) to the mantle, or to the rim beyond its ends."""
        v = np.asarray(points) - self.center
        t = v @ self.axis
        radial = np.linalg.norm(v - np.outer(t, self.axis), axis=1) - self.radius
        beyond = np.abs(t) - self.height / 2
        return np.where(beyond > 0, np.hypot(np.maximum(radial, 0), beyond), np.abs(radial))


class SphereModel(Model):
    kind: Literal["sphere"] = "sphere"
    center: Vec3
    radius: float = Field(gt=0)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of points (n, 3) to the surface."""
        return np.abs(np.linalg.norm(np.asarray(points) - self.center, axis=1) - self.radius)


class BoxModel(Model):
    """A cuboid: centre, rotation (columns = box axes), full side lengths."""

    kind: Literal["box"] = "box"
    center: Vec3
    rotation: Annotated[np.ndarray, Array("float64", (3, 3)), Finite()]
    extent: Annotated[np.ndarray, Array("float64", (3,)), Finite()]

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of points (n, 3) to the box's surface, inside or out."""
        q = np.abs((np.asarray(points) - self.center) @ self.rotation) - self.extent / 2
        outside = np.linalg.norm(np.maximum(q, 0), axis=1)
        return np.abs(outside + np.minimum(q.max(axis=1), 0))


PrimitiveModel = Annotated[
    PlaneModel | CylinderModel | SphereModel | BoxModel, Field(discriminator="kind")
]


class Primitive(Model):
    """One fitted primitive ψ with its model parameters, OBB(ψ) and inlier cloud P_ψ (Eq. 3.3)."""

    id: int = Field(ge=0)
    model: PrimitiveModel
    obb: Obb
    inlier_count: int = Field(ge=0, description="inliers of the fit, before downsampling")
    inliers: Annotated[
        np.ndarray, Array("float32", (None, 3), max_rows=MAX_INLIERS, description="world, m")
    ]
    colour: Annotated[np.ndarray, Array("uint8", (3,))] = Field(
        default_factory=lambda: np.zeros(3, np.uint8)
    )

    @property
    def kind(self) -> PrimitiveKind:
        return self.model.kind


class SpatialEdge(Model):
    """Undirected spatial relation: ε-extended OBBs intersect (Eq. 3.5, 3.6)."""

    a: int
    b: int


class SupportEdge(Model):
    """SUPP(supporter, supported): removing ``supporter`` makes ``supported`` move (3.2.2).
    ``occ`` counts the views in which the edge was extracted (3.3.1)."""

    supporter: int
    supported: int
    occ: int = Field(1, ge=1)
    contact: Vec3 | None = None


class Affordance(Model):
    """An interaction possibility of a primitive for the robot's hand(s) (3.2.3)."""

    kind: AffordanceKind
    primitive_id: int
    poses: Poses = Field(description="end-effector poses T_world_hand that realise it")
    confidence: float = Field(ge=0, le=1)
    bimanual: bool = False


class SceneGraph(Model):
    """Primitives with their spatial graph, support graph and affordances."""

    primitives: list[Primitive] = Field(default_factory=list)
    spatial_edges: list[SpatialEdge] = Field(default_factory=list)
    support_edges: list[SupportEdge] = Field(default_factory=list)
    root_id: int | None = Field(None, description="ρ, the lowest primitive (Eq. 3.4)")
    unstable_ids: list[int] = Field(
        default_factory=list, description="primitives with no support path to ρ"
    )
    unresolved_ids: list[int] = Field(
        default_factory=list,
        description="of the primitives with no support path to ρ, those whose support no view"
        " could see (nothing seen under them yet: an incomplete model, thesis 3.2.2); the"
        " scene memory moves these out of unstable_ids",
    )
    affordances: list[Affordance] = Field(default_factory=list)

    @model_validator(mode="after")
    def _references_exist(self) -> SceneGraph:
        ids = [p.id for p in self.primitives]
        known = set(ids)
        if len(known) != len(ids):
            raise ValueError("primitive ids must be unique")
        refs = [("root_id", self.root_id)] if self.root_id is not None else []
        refs += [("spatial_edges", i) for e in self.spatial_edges for i in (e.a, e.b)]
        refs += [
            ("support_edges", i) for e in self.support_edges for i in (e.supporter, e.supported)
        ]
        refs += [("unstable_ids", i) for i in self.unstable_ids]
        refs += [("unresolved_ids", i) for i in self.unresolved_ids]
        refs += [("affordances", a.primitive_id) for a in self.affordances]
        for where, i in refs:
            if i not in known:
                raise ValueError(f"{where} refers to primitive {i}, which is not in primitives")
        return self


class SceneObservation(SceneGraph, Stamped):
    """The semantic scene perceived in one RGB-D frame (perception/observation). v2: the
    graph's ``unresolved_ids`` (empty: perception's unstable are those of one view)."""

    VERSION: ClassVar[int] = 2

    camera: str
    frame_seq: int = Field(ge=0, description="seq of the RgbdFrame this was computed from")
    frame_stamp: float
    worker: str = Field("", description="instance of the perception worker that made it")
    T_world_camera: Pose
    intrinsics: CameraIntrinsics
    depth_max: float = Field(3.0, gt=0, description="farthest depth used, m")
    points: int = Field(0, ge=0, description="valid points in the frame's cloud")
    timings_ms: dict[str, float] = Field(default_factory=dict)


class SceneModel(SceneGraph, Stamped):
    """The fused scene across views (memory/scene), with occ(e) on support edges. v2:
    ``frame_seq`` and ``frame_stamp``, the frame whose observation the model fused last. v3:
    ``fused_frames``, every frame whose observation this model is the first to hold (the scene
    memory publishes one model for all the observations that waited while it fused). v4:
    ``unresolved_ids``, moved out of ``unstable_ids`` (nothing seen under them yet)."""

    VERSION: ClassVar[int] = 4

    model_version: int = Field(ge=0, description="increases with every accepted update")
    n_views: int = Field(ge=0)
    fusion: Literal["pc", "sg", "pc+sg"]
    added: int = Field(0, ge=0, description="primitives added by the last update")
    modified: int = Field(0, ge=0)
    removed: int = Field(0, ge=0)
    frame_seq: int | None = Field(
        None,
        ge=0,
        description="seq of the RgbdFrame (or registered cloud) whose observation the model "
        "fused last; None before the first",
    )
    frame_stamp: float | None = Field(None, description="that frame's capture stamp")
    fused_frames: list[int] = Field(
        default_factory=list,
        description="seqs of the frames whose observations were fused since the model "
        "published before this one, in order (frame_seq is the last); empty in a reply to a "
        "query",
    )


class PointCloud(Stamped):
    """A point cloud in the world frame (memory/cloud: the registered cloud, voxel-downsampled)."""

    points: Annotated[np.ndarray, Array("float32", ("n", 3), description="world, m")]
    colours: Annotated[np.ndarray, Array("uint8", ("n", 3))] | None = None
    voxel_size: float = Field(0.0, ge=0, description="downsampling voxel, 0 if none")


class PoseCorrection(Stamped):
    """What view registration (A.5) found the odometry to be off by (memory/pose_correction),
    estimated on one frame: T_world = T_world_odom · T_odometry for the platform and everything
    on it. ``accepted`` false: this frame could not be registered (``reason``) and
    ``T_world_odom`` is still the last accepted correction."""

    T_world_odom: Pose
    camera: str
    frame_seq: int = Field(ge=0)
    accepted: bool
    reason: str = ""
    fitness: float = Field(0.0, ge=0, le=1, description="share of the frame's points on the map")
    rmse: float = Field(0.0, ge=0, description="of the matched points, m (0: none matched)")
    registration_ms: float = Field(0.0, ge=0)
    refused: int = Field(0, ge=0, description="frames not registered so far")
