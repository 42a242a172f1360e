"""What the robot knows of the scene across views: the fused primitives (Algorithm 2) with
their support graph, the occupancy map, and the registered point cloud. Pure: arrays and wire
messages in, state out; the node adds transport and persistence."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from schemas import CloudFrame, PointCloud, RgbdFrame, SceneModel, SceneObservation
from services.scene_memory.cloud_merge import add_frame
from services.scene_memory.correction_filter import CorrectionFilter
from services.scene_memory.fusion import Fusion, FusionConfig, Update, voxel_keys
from services.scene_memory.hypotheses import RETRY, SearchConfig, search
from services.scene_memory.occupancy import OccupancyConfig, OccupancyMap
from services.scene_memory.registration import (
    RegistrationConfig,
    RegistrationMap,
    moved,
    register,
)

MAX_CLOUD = 400_000  # points the registered cloud keeps
#: the camera name of ``registered_cloud``'s clouds: what is perceived in them is in the map
REGISTERED_CAMERA = "registered"
#: points of the roi's registered cloud that ``pc`` fusion re-extracts from, at most
MAX_ROI_CLOUD = 60_000
#: ``SceneMemory.fuse``'s default correction: the last registration's
LAST = object()
#: the reason a registration was refused that the odometry's uncertainty and the
#: registration's own cannot explain (``CorrectionFilter.mahalanobis``)
INCONSISTENT = "inconsistent_with_odometry"
#: the reason a frame was not registered: the last registration is more recent than
#: ``MemoryConfig.registration_interval`` (the frame took the last correction)
NOT_DUE = "not_due"


@dataclass
class MemoryConfig:
    bounds_min: tuple[float, float, float] = (-1.0, -2.5, -0.05)
    bounds_max: tuple[float, float, float] = (4.0, 2.5, 2.2)
    cloud_voxel: float = 0.01
    depth_min: float = 0.35
    #: every ``map_stride``-th pixel of a depth frame, each way, casts a ray into the occupancy
    #: map: at 2, 7 mm apart at 2 m (a 1 cm voxel's face still gets a return up to 2.8 m), a
    #: quarter of the returns to merge and a third less to walk; the free space the same within
    #: 0.1 % on a kitchen pan, the occupied voxels fewer (a surface's noise less thick)
    map_stride: int = 2
    #: keyframes: a depth frame is integrated once the camera moved this far (m) or turned
    #: this much (degrees) since the last integrated one; 0 and 0 integrate every frame
    keyframe_move: float = 0.0
    keyframe_turn: float = 0.0
    #: the region whose unknown voxels the views resolve (realised information gain)
    roi: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    fusion: FusionConfig = field(default_factory=FusionConfig)
    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    #: view registration (A.5) of each integrated frame against the cloud so far; None: the
    #: frames' poses are taken as they come
    registration: RegistrationConfig | None = None
    #: ... at most every this many seconds of capture time (the frames' stamps): a frame in
    #: between is placed by the last correction (odometry drifts over seconds, not from one
    #: frame to the next at 15 fps) and not added to the registration map; 0: every frame
    registration_interval: float = 0.0
    #: where the local registration is refused as too far from the map, it is registered
    #: again from seeds over the odometry's uncertainty and taken when one answer stands out
    #: (``hypotheses``); None: the local answer stands
    search: SearchConfig | None = field(default_factory=SearchConfig)


class SceneMemory:
    #: the odometry's correction found by the last accepted registration: T_world =
    #: T_world_odom · T_odometry (None: identity); the prior of the next frame's registration
    T_world_odom: np.ndarray | None = None
    #: the last registration's outcome (accepted, reason, fitness, rmse, ms), and the count of
    #: refused ones
    last_registration: dict | None = None
    registrations_refused: int = 0
    #: the capture stamp of the last frame registration was tried on (None: none yet), and the
    #: frames since placed by the last correction instead (``registration_interval``)
    registered_stamp: float | None = None
    #: the capture time of the last frame registered again by a search (``hypotheses``)
    searched_stamp: float | None = None
    registrations_not_due: int = 0
    #: what frames are registered against (``registration``): built as frames are integrated,
    #: rebuilt from the registered cloud for a snapshot written before it existed
    registration_map: RegistrationMap | None = None
    #: the correction and its uncertainty (``RegistrationConfig.odometry_noise``; None: not
    #: weighed, or no frame yet)
    correction_filter: CorrectionFilter | None = None
    #: (n, 3) float32: the optical centre each point of ``cloud`` was seen from (None: a
    #: snapshot from before they were kept)
    viewpoints: np.ndarray | None = None
    #: (seq, capture stamp) of the frame whose observation was fused last (None: none yet):
    #: the scene model names it, so a reader can tell how far behind the camera it is
    fused_frame: tuple[int, float] | None = None
    #: the cloud's voxel keys, point by point and sorted (``_index``; not in snapshots)
    _cloud_keys: np.ndarray | None = None
    _cloud_index: np.ndarray | None = None

    def __init__(self, config: MemoryConfig | None = None) -> None:
        self.config = config or MemoryConfig()
        c = self.config
        self.fusion = Fusion(c.fusion)
        self.occupancy = OccupancyMap(np.array(c.bounds_min), np.array(c.bounds_max), c.occupancy)
        self.cloud = np.zeros((0, 3), np.float32)
        self.colours = np.zeros((0, 3), np.uint8)
        self.viewpoints = np.zeros((0, 3), np.float32)
        self.timings_ms: dict[str, float] = {}
        #: the information gain the last frame realised in the roi, by both of the planner's
        #: measures: "volume" (unknown voxels it made known) and "rays" (Eq. 4.6 on its rays)
        self.realised_gain: dict[str, float] = {"volume": 0.0, "rays": 0.0}
        self.last_keyframe: np.ndarray | None = None  # T_world_camera of the last integrated
        self.frames_skipped = 0

    def is_keyframe(self, T_world_camera: np.ndarray) -> bool:
        """Whether a frame from this camera pose adds to the map: the camera moved more than
        ``keyframe_move`` or turned more than ``keyframe_turn`` since the last integrated one."""
        c, last = self.config, self.last_keyframe
        if last is None or (c.keyframe_move <= 0 and c.keyframe_turn <= 0):
            return True
        moved = float(np.linalg.norm(T_world_camera[:3, 3] - last[:3, 3]))
        cos = (np.trace(last[:3, :3].T @ T_world_camera[:3, :3]) - 1) / 2
        turned = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
        return moved > c.keyframe_move or turned > c.keyframe_turn

    def skip(self) -> None:
        """A frame that was not a keyframe: counted; it made nothing known."""
        self.frames_skipped += 1
        self.realised_gain = {"volume": 0.0, "rays": 0.0}

    def integrate(self, frame: RgbdFrame, registered: Callable[[], None] | None = None) -> int:
        """Add a depth frame to the occupancy map and the registered cloud; ``registered`` is
        called once its pose is final (registration done, ``T_world_odom`` updated), before
        the map's part, the long one."""
        if frame.depth is None:
            return 0
        self.last_keyframe = np.array(frame.T_world_camera, float)
        t0 = time.perf_counter()
        K = frame.intrinsics
        max_range = min(self.config.occupancy.max_range, frame.depth_max or np.inf)
        # the frame's timings replace the last frame's; fusion's (``fuse_ms``) stay: the node
        # may fuse meanwhile on another thread, so the dict is updated, never replaced
        for key in ("registration_ms", "registration_map_ms"):
            self.timings_ms.pop(key, None)
        # the frame's points, every 2nd pixel, in its camera's frame: registered, then the cloud
        z = frame.depth[::2, ::2]
        v, u = np.nonzero((z > self.config.depth_min) & (z <= max_range))
        d = z[v, u].astype(np.float64)
        cam = np.column_stack([(2 * u - K.cx) / K.fx * d, (2 * v - K.cy) / K.fy * d, d])
        T, placed = self.registered_pose(frame, cam)
        if registered is not None:
            registered()
        roi = self.config.roi
        if roi is not None:
            rays = self.occupancy.unknown_on_rays(
                frame.depth, (K.fx, K.fy, K.cx, K.cy), T, roi, self.config.depth_min, max_range
            )
        k = self.config.map_stride
        n = self.occupancy.integrate_depth(
            frame.depth[::k, ::k], K.fx / k, K.fy / k, K.cx / k, K.cy / k, T,
            self.config.depth_min, max_range, roi,
        )  # fmt: skip
        if roi is not None:  # the roi's voxels the frame made known, counted as it updated them
            self.realised_gain = {"volume": float(self.occupancy.made_known), "rays": rays}
        t1 = time.perf_counter()
        pts = cam @ T[:3, :3].T + T[:3, 3]
        if self.config.registration is not None and placed:
            # only frames that registration placed (or the first, which defines the map): a
            # refused frame, fused where odometry puts it, would give the next frame a
            # misplaced copy of the scene to align to
            t2 = time.perf_counter()
            self._registration_map().add(pts, T[:3, 3])
            self.timings_ms["registration_map_ms"] = (time.perf_counter() - t2) * 1e3
        rgb = (
            frame.rgb[::2, ::2][v, u]
            if frame.rgb is not None
            else np.zeros((len(pts), 3), np.uint8)
        )
        self._add_to_cloud(pts.astype(np.float32), rgb, T[:3, 3])
        self.timings_ms["integrate_ms"] = (t1 - t0) * 1e3
        self.timings_ms["cloud_ms"] = (time.perf_counter() - t1) * 1e3
        return n

    def _add_to_cloud(self, pts: np.ndarray, rgb: np.ndarray, eye: np.ndarray) -> None:
        """Merge a frame's points into the registered cloud, one point per voxel of
        ``cloud_voxel`` (a voxel's first point stays), the oldest dropped beyond MAX_CLOUD
        (``cloud_merge.add_frame``, one compiled call: the frame's points are sorted and merged with
        the cloud's sorted voxel keys, ``_cloud_index``; re-sorting the whole cloud each frame
        cost 30 ms of a kitchen frame)."""
        viewpoints, index = self._viewpoints(), self._index()
        self.cloud, self.colours, self.viewpoints, self._cloud_keys, self._cloud_index = (
            add_frame(
                self.cloud, self.colours, viewpoints, self._cloud_keys, index,
                np.asarray(pts, np.float32), np.asarray(rgb, np.uint8),
                np.asarray(eye, np.float32), self.config.cloud_voxel, MAX_CLOUD,
            )
        )  # fmt: skip

    def _index(self) -> np.ndarray:
        """The sorted voxel keys of the cloud (and ``_cloud_keys``, the cloud point by point):
        rebuilt when missing (a restored snapshot leaves them out)."""
        keys = self._cloud_keys
        if keys is None or len(keys) != len(self.cloud) or self._cloud_index is None:
            self._cloud_keys = voxel_keys(self.cloud, self.config.cloud_voxel)
            self._cloud_index = np.sort(self._cloud_keys)
        return self._cloud_index

    #: arrays a snapshot keeps without a copy: the cloud's are replaced, never written in place
    SNAPSHOT_AS_IS = frozenset({"cloud", "colours", "viewpoints"})

    def __getstate__(self) -> dict:
        """Snapshots leave the cloud's voxel keys out: ``_index`` rebuilds them."""
        state = dict(self.__dict__)
        state.pop("_cloud_keys", None)
        state.pop("_cloud_index", None)
        return state

    def _viewpoints(self) -> np.ndarray:
        """Where each point of the cloud was seen from; for a cloud restored from a snapshot
        that did not keep it, the last camera (or above the cloud)."""
        v = self.viewpoints
        if v is not None and len(v) == len(self.cloud):
            return v
        if len(self.cloud) == 0:
            return np.zeros((0, 3), np.float32)
        T = self.last_keyframe
        eye = T[:3, 3] if T is not None else self.cloud.mean(0) + np.array([0, 0, 1.0])
        return np.broadcast_to(np.asarray(eye, np.float32), self.cloud.shape).copy()

    def registered_pose(self, frame: RgbdFrame, cam: np.ndarray) -> tuple[np.ndarray, bool]:
        """The frame's camera pose in the map: its odometry pose corrected by the last
        correction, refined against the cloud so far when registration is on (A.5), from the
        frame's points ``cam`` (camera frame); and whether registration placed it (or it is the
        first frame, which defines the map)."""
        T_odom = np.asarray(frame.T_world_camera, float)
        prior = T_odom if self.T_world_odom is None else self.T_world_odom @ T_odom
        c = self.config.registration
        weigh = c is not None and c.odometry_noise is not None
        if weigh:
            if self.correction_filter is None:
                self.correction_filter = CorrectionFilter(
                    c.dof, c.odometry_noise, c.registration_noise, self.T_world_odom
                )
            self.correction_filter.predict(T_odom)
        if c is None or len(self.cloud) == 0:
            return prior, len(self.cloud) == 0
        if not self.registration_due(frame.stamp):
            self.registrations_not_due += 1
            self.last_registration = {
                "accepted": False, "reason": NOT_DUE, "fitness": 0.0, "rmse": 0.0, "ms": 0.0,
                "stamp": frame.stamp,
            }  # fmt: skip
            return prior, False
        self.registered_stamp = frame.stamp
        result = register(cam, prior, self._registration_map(), c)
        s, searched = self.config.search, False
        if (
            not result.accepted
            and s is not None
            and result.reason in RETRY
            and _due(self.searched_stamp, frame.stamp, s.interval)
        ):
            self.searched_stamp, searched = frame.stamp, True
            found, _ = search(cam, prior, self._registration_map(), c, s, self.cloud)
            found.ms += result.ms
            if found.accepted or found.reason == "ambiguous":
                result = found
        self.last_registration = {
            "accepted": result.accepted, "reason": result.reason, "fitness": result.fitness,
            "rmse": result.rmse, "ms": result.ms, "stamp": frame.stamp, "searched": searched,
        }  # fmt: skip
        self.timings_ms["registration_ms"] = result.ms
        if not result.accepted:
            self.registrations_refused += 1
            return prior, False
        measured = result.T_world_camera @ np.linalg.inv(T_odom)
        f = self.correction_filter
        if weigh and f is not None:
            d2 = f.mahalanobis(measured)
            self.last_registration["mahalanobis"] = d2
            if d2 > c.max_mahalanobis[c.dof]:
                self.last_registration |= {"accepted": False, "reason": INCONSISTENT}
                self.registrations_refused += 1
                return prior, False
            measured = f.update(measured)
        self.T_world_odom = measured
        return measured @ T_odom, True

    def will_register(self, frame: RgbdFrame) -> bool:
        """Whether integrating ``frame`` would register it (and so may move ``T_world_odom``):
        registration on, a cloud to register against, and its time come."""
        return (
            self.config.registration is not None
            and len(self.cloud) > 0
            and self.registration_due(frame.stamp)
        )

    def registration_due(self, stamp: float) -> bool:
        """Whether a frame captured at ``stamp`` is registered: ``registration_interval`` has
        passed since the last one was (or time went back: a reset sim)."""
        return _due(self.registered_stamp, stamp, self.config.registration_interval)

    def _registration_map(self) -> RegistrationMap:
        if self.registration_map is None:
            self.registration_map = RegistrationMap.of(
                self.cloud, self.config.registration, self._viewpoints()
            )
        return self.registration_map

    def fuse(self, obs: SceneObservation, correction: object = LAST) -> Update:
        """Fuse an observation (Algorithm 2), moved into the registered map by the odometry's
        ``correction`` (default: ``T_world_odom``, the last registration's; None: none). One
        perceived in the registered cloud (``registered_cloud``) is in the map already, and saw
        the whole roi at once. Fusion reads nothing else of the map's side (the occupancy map,
        the cloud, registration): the node fuses on one thread while frames are integrated on
        another, handing it the correction it journaled with the observation."""
        t0 = time.perf_counter()
        whole = obs.camera == REGISTERED_CAMERA
        T = self.T_world_odom if correction is LAST else correction
        if T is not None and not whole:
            obs = moved(obs, np.asarray(T, float))
        update = self.fusion.update(obs, whole=whole)
        self.fused_frame = (obs.frame_seq, obs.frame_stamp)
        self.timings_ms["fuse_ms"] = (time.perf_counter() - t0) * 1e3
        return update

    def scene(
        self, seq: int = 0, stamp: float = 0.0, fused_frames: list[int] | None = None
    ) -> SceneModel:
        """The scene model; ``fused_frames``: the frames whose observations it is the first
        to hold (see ``SceneModel``)."""
        frame_seq, frame_stamp = self.fused_frame or (None, None)
        return self.fusion.scene_model(seq, stamp, frame_seq, frame_stamp, fused_frames)

    def point_cloud(self, seq: int = 0, stamp: float = 0.0, cap: int = 100_000) -> PointCloud:
        idx = np.linspace(0, len(self.cloud) - 1, min(cap, len(self.cloud))).astype(int)
        return PointCloud(
            seq=seq,
            stamp=stamp,
            points=self.cloud[idx],
            colours=self.colours[idx],
            voxel_size=self.config.cloud_voxel,
        )


def registered_cloud(
    memory: SceneMemory,
    frame: RgbdFrame,
    box: tuple | None = None,
    voxel: float = 0.01,
    margin: float = 0.03,
    cap: int = MAX_ROI_CLOUD,
) -> CloudFrame:
    """The registered cloud of ``box`` (default: the roi; grown by ``margin``; without either,
    all of it), every view so far merged in the map, voxel-downsampled to ``voxel`` (at most
    ``cap`` points, evenly spread): what ``pc`` fusion re-extracts the scene from (thesis 3.3.1,
    Table 3.1: P^{1,t} = P_1 ∪ … ∪ P_t). Its pose is ``frame``'s camera in the map (odometry
    corrected by registration), each point carries the camera centre it was seen from."""
    points, seen_from, colours = memory.cloud, memory._viewpoints(), memory.colours
    roi = box if box is not None else memory.config.roi
    if roi is not None and len(points):
        lo, hi = np.asarray(roi[0]) - margin, np.asarray(roi[1]) + margin
        inside = np.all((points >= lo) & (points <= hi), axis=1)
        points, seen_from, colours = points[inside], seen_from[inside], colours[inside]
    if voxel > memory.config.cloud_voxel and len(points):
        _, first = np.unique(voxel_keys(points, voxel), return_index=True)
        first = np.sort(first)
        points, seen_from, colours = points[first], seen_from[first], colours[first]
    if len(points) > cap:
        keep = np.linspace(0, len(points) - 1, cap).astype(int)
        points, seen_from, colours = points[keep], seen_from[keep], colours[keep]
    T = np.asarray(frame.T_world_camera, float)
    if memory.T_world_odom is not None:
        T = memory.T_world_odom @ T
    return CloudFrame(
        seq=frame.seq,
        stamp=frame.stamp,
        camera=REGISTERED_CAMERA,
        frame_seq=frame.seq,
        T_world_camera=T,
        intrinsics=frame.intrinsics,
        points=np.ascontiguousarray(points, np.float32),
        viewpoints=np.ascontiguousarray(seen_from, np.float32),
        colours=np.ascontiguousarray(colours, np.uint8),
        voxel_size=max(voxel, memory.config.cloud_voxel),
        depth_max=frame.depth_max,
    )


def _due(last: float | None, stamp: float, interval: float) -> bool:
    """Whether ``interval`` seconds of capture time have passed since ``last`` (None: never),
    or time went back (a reset sim: its clock starts again)."""
    return last is None or interval <= 0 or not 0 <= stamp - last < interval
