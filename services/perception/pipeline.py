"""The perception pipeline of one frame, stage by stage, with the time of each stage:

cloud → segmentation → primitives (Algorithm 1) → boxes → spatial graph → support graph →
stability → affordances.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from schemas import (
    Affordance,
    BoxModel,
    CameraIntrinsics,
    CloudFrame,
    CylinderModel,
    Obb,
    PlaneModel,
    Primitive,
    RgbdFrame,
    SceneObservation,
    SpatialEdge,
    SphereModel,
    SupportEdge,
)
from services.common.sat import pairs_overlap
from services.perception import kernels, ransac, relations
from services.perception.affordances import AffordanceOut, Hand, affordances
from services.perception.cloud import organized_cloud
from services.perception.obb import Box, intersect
from services.perception.pointset import point_set, segment_points
from services.perception.primitives import (
    Extracted,
    ExtractionConfig,
    assemble_boxes,
    extract_segment,
)
from services.perception.segmentation import segment

MAX_INLIERS = 2000
UP = np.array([0.0, 0.0, 1.0])


@dataclass
class PointSetConfig:
    """Perceiving an unorganized cloud (``perceive_points``): at 1 cm voxels a surface has a
    quarter of the points the stride-2 grid gives it at 1.5 m, so the least primitive and
    segment are smaller in points (about the same in area)."""

    radius: float = 0.02  # neighbours within this distance (2 voxels of the memory's cloud)
    crease_deg: float = 30.0
    min_segment: int = 15
    extraction: ExtractionConfig = field(default_factory=lambda: ExtractionConfig(tau_min=20))


@dataclass
class PerceptionConfig:
    depth_min: float = 0.35
    depth_max: float = 3.0
    stride: int = 2
    smooth: int = 3
    #: normals over a window of half-width round(smooth_per_m2 · z²) where that is wider
    #: (``organized_cloud``; at 0.45: 1 up to 1.8 m, 3 at 2.5 m, 4 at 3 m); 0: ``smooth``
    #: everywhere. Off by default: on the simulated kitchen orbit (tests/scene_memory/
    #: test_kitchen.py) 0.3 already rounds the far counters' creases off (OverlappingIndex
    #: 0.82 → 0.79); on the real redkitchen 0.45 takes the wall's crackle away
    smooth_per_m2: float = 0.0
    min_segment: int = 30
    seed: int = 0
    extraction: ExtractionConfig = field(default_factory=ExtractionConfig)
    relations: relations.RelationConfig = field(default_factory=relations.RelationConfig)
    hand: Hand = field(default_factory=Hand)
    points: PointSetConfig = field(default_factory=PointSetConfig)


@dataclass
class Perceived:
    primitives: list[Extracted]
    spatial: list[tuple[int, int]]
    support: list[tuple[int, int, np.ndarray]]
    root: int | None
    unstable: list[int]
    affordances: list[AffordanceOut]
    points: int
    timings_ms: dict[str, float]
    grid_shape: tuple[int, int] = (0, 0)


class Laps:
    """Stage timings (ms): ``lap(stage)`` closes the stage that began at the previous lap."""

    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self.t = time.perf_counter()

    def __call__(self, stage: str) -> None:
        now = time.perf_counter()
        self.timings[stage] = (now - self.t) * 1e3
        self.t = now


class Perception:
    """The pipeline with its configuration; ``perceive`` is a pure function of the frame."""

    def __init__(self, config: PerceptionConfig | None = None) -> None:
        self.config = config or PerceptionConfig()

    def warm_up(self) -> None:
        """Run once on a small synthetic frame: loads the compiled kernels before the first
        real frame arrives."""
        z = np.full((48, 64), 1.0, np.float32)
        z[10:30, 20:40] = 0.8
        rgb = np.full((48, 64, 3), 200, np.uint8)
        rgb[10:30, 20:40] = (200, 40, 40)  # a red box before a grey wall: colour edges
        K = CameraIntrinsics.from_fov(64, 48, 45.0)
        self.perceive(z, None, K, np.eye(4))
        self.perceive(z, rgb, K, np.eye(4))
        table = Box(np.zeros(3), np.eye(3), np.array([1.0, 1.0, 0.1]))  # two primitives' boxes:
        cup = Box(np.array([0, 0, 0.1]), np.eye(3), np.full(3, 0.1))
        intersect(table, cup, 0.01)
        both = [table, cup]
        pairs_overlap(
            *(np.stack([getattr(b, k) for b in both]) for k in ("rotation", "center", "extent"))
        )
        kernels.face_contact(cup.corners(), table.center, table.rotation, table.extent / 2, 0.02)
        ransac.cylinder_arc(np.eye(3), UP)  # a curved fit's tests (the frame above may have none)
        ransac.sphere_spread(np.eye(3))

    def perceive(
        self,
        depth: np.ndarray,
        rgb: np.ndarray | None,
        intrinsics: CameraIntrinsics,
        T_world_camera: np.ndarray,
        mask: np.ndarray | None = None,
    ) -> Perceived:
        """``mask``: pixels to leave out (the robot's own body, ``self_mask``)."""
        c = self.config
        if mask is not None and mask.any():
            depth = np.where(mask, np.float32(0), np.asarray(depth, np.float32))
        rng = np.random.default_rng(c.seed)
        lap = Laps()
        cloud = organized_cloud(
            depth,
            rgb,
            intrinsics.fx,
            intrinsics.fy,
            intrinsics.cx,
            intrinsics.cy,
            T_world_camera,
            depth_min=c.depth_min,
            depth_max=c.depth_max,
            stride=c.stride,
            smooth=c.smooth,
            smooth_per_m2=c.smooth_per_m2,
        )
        lap("cloud")
        labels, n = segment(cloud, min_size=c.min_segment)
        lap("segmentation")
        return self._scene(cloud, labels, n, c.extraction, T_world_camera[:3, 3], lap, rng)

    def perceive_points(
        self,
        points: np.ndarray,
        viewpoints: np.ndarray,
        colours: np.ndarray | None = None,
        camera_centre: np.ndarray | None = None,
    ) -> Perceived:
        """The same stages on an unorganized world cloud (``pointset.py``): the registered
        cloud of many views, which ``pc`` fusion re-extracts the scene from. ``viewpoints``:
        the optical centre each point was seen from (its normal faces it); ``camera_centre``:
        the latest camera (affordances are for the robot there)."""
        c, pc = self.config, self.config.points
        rng = np.random.default_rng(c.seed)
        lap = Laps()
        cloud = point_set(points, viewpoints, colours, camera_centre, pc.radius)
        lap("cloud")
        labels, n = segment_points(cloud, pc.min_segment, pc.crease_deg)
        lap("segmentation")
        return self._scene(cloud, labels, n, pc.extraction, cloud.camera_centre, lap, rng)

    def _scene(self, cloud, labels, n, extraction, eye, lap: Laps, rng) -> Perceived:
        """Algorithm 1 on every segment, then boxes, the graphs and affordances."""
        c = self.config
        flat = labels.ravel()
        order = np.argsort(flat, kind="stable")
        bounds = np.searchsorted(flat[order], np.arange(n + 1))
        prims: list[Extracted] = []
        for s in range(n):
            prims += extract_segment(cloud, order[bounds[s] : bounds[s + 1]], s, extraction, rng)
        lap("primitives")
        prims = assemble_boxes(prims, extraction)
        lap("boxes")
        spatial = relations.spatial_edges(prims, c.relations)
        lap("spatial_graph")
        support = relations.support_edges(prims, spatial, c.relations)
        relations.settle_on_supports(prims, support, c.relations)
        root = relations.root(prims)
        ground = relations.grounded(prims, root, c.relations)
        # a ground surface (the table top) rests only on ground (the floor), not on the legs
        # that hold it up: those are parts of one piece of furniture
        support = [e for e in support if e[1] not in ground or e[0] in ground]
        unstable = relations.unstable(len(prims), ground, support)
        lap("support_graph")
        resting = {t for _, t, _ in support}
        affs = affordances(prims, eye, resting, c.hand)
        lap("affordances")
        timings = lap.timings
        timings["total"] = sum(timings.values())
        return Perceived(
            prims,
            spatial,
            support,
            root,
            unstable,
            affs,
            int(cloud.valid.sum()),
            timings,
            cloud.shape,
        )


def _model(p: Extracted):
    if p.kind == "plane":
        return PlaneModel(normal=p.normal, d=p.d)
    if p.kind == "cylinder":
        return CylinderModel(center=p.center, axis=p.axis, radius=p.radius, height=p.height)
    if p.kind == "sphere":
        return SphereModel(center=p.center, radius=p.radius)
    return BoxModel(center=p.center, rotation=p.rotation, extent=p.extent)


def to_primitive(
    index: int, p: Extracted, colours: np.ndarray | None, rng: np.random.Generator
) -> Primitive:
    """``colours``: the perceived grid's RGB, (pixels, 3)."""
    points = p.points
    if len(points) > MAX_INLIERS:
        points = points[np.sort(rng.choice(len(points), MAX_INLIERS, replace=False))]
    colour = (
        colours[p.pixels].mean(0).round().astype(np.uint8)
        if colours is not None
        else np.zeros(3, np.uint8)
    )
    return Primitive(
        id=index,
        model=_model(p),
        obb=Obb(center=p.box.center, rotation=p.box.rotation, extent=p.box.extent),
        inlier_count=len(p.pixels),
        inliers=points.astype(np.float32),
        colour=colour,
    )


def observation(
    result: Perceived, frame: RgbdFrame, seq: int, worker: str, depth_max: float, stride: int
) -> SceneObservation:
    """The SceneObservation message of one perceived frame."""
    # (one contiguous copy of the strided image, its pixels in rows: reshaping the strided
    # view per primitive copied the whole image each time, 4 ms of a 40 ms frame)
    colours = (
        np.ascontiguousarray(frame.rgb[::stride, ::stride]).reshape(-1, 3)
        if frame.rgb is not None
        else None
    )
    return _observation(result, frame, colours, seq, worker, depth_max)


def cloud_observation(
    result: Perceived, cloud: CloudFrame, seq: int, worker: str
) -> SceneObservation:
    """The SceneObservation message of a perceived world cloud (``perceive_points``): its
    pose and intrinsics are those of the view that completed the cloud."""
    return _observation(result, cloud, cloud.colours, seq, worker, cloud.depth_max or 3.0)


def _observation(
    result: Perceived,
    source: RgbdFrame | CloudFrame,
    colours: np.ndarray | None,
    seq: int,
    worker: str,
    depth_max: float,
) -> SceneObservation:
    rng = np.random.default_rng(source.seq)
    frame_seq = source.frame_seq if isinstance(source, CloudFrame) else source.seq
    return SceneObservation(
        seq=seq,
        stamp=source.stamp,
        camera=source.camera,
        frame_seq=frame_seq,
        frame_stamp=source.stamp,
        worker=worker,
        T_world_camera=source.T_world_camera,
        intrinsics=source.intrinsics,
        depth_max=depth_max,
        points=result.points,
        primitives=[to_primitive(i, p, colours, rng) for i, p in enumerate(result.primitives)],
        spatial_edges=[SpatialEdge(a=a, b=b) for a, b in result.spatial],
        support_edges=[
            SupportEdge(supporter=s, supported=t, contact=c) for s, t, c in result.support
        ],
        root_id=result.root,
        unstable_ids=result.unstable,
        affordances=[
            Affordance(
                kind=a.kind,
                primitive_id=a.primitive,
                poses=a.poses,
                confidence=a.confidence,
                bimanual=a.bimanual,
            )
            for a in result.affordances
        ],
        timings_ms=result.timings_ms,
    )
