"""The scene memory's node: observations and depth frames in (each journaled before it is
applied), the fused scene out on every change, and its state on queryables.

In ``pc`` and ``pc+sg`` fusion it also publishes, after each depth frame, the registered
cloud of the roi (every view so far merged in the map, voxel-downsampled, each point with the
camera centre it was seen from) on ``sensors/cloud/registered``: a perception worker run with
``--camera registered`` re-extracts the primitives and support graph from that whole cloud
(thesis 3.3.1), and only those observations are fused.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterator

import msgpack
import numpy as np

from schemas import (
    BoxQuery,
    OccupancySlice,
    OccupancyStats,
    PointCloud,
    PoseCorrection,
    RgbdFrame,
    SceneModel,
    SceneObservation,
    decode,
    encode,
)
from services.common.frames import usable_depth_frame
from services.common.node import Node
from services.common.realtime import BACKGROUND, FOREGROUND
from services.common.standby import wait_for_turn
from services.scene_memory import kernels
from services.scene_memory.config import SceneMemorySettings
from services.scene_memory.correction_filter import OdometryNoise, RegistrationNoise
from services.scene_memory.fusion import FusionConfig
from services.scene_memory.hypotheses import SearchConfig
from services.scene_memory.memory import (
    REGISTERED_CAMERA,
    MemoryConfig,
    SceneMemory,
    registered_cloud,
)
from services.scene_memory.occupancy import OccupancyConfig
from services.scene_memory.persistence import Store, snapshot_due
from services.scene_memory.registration import RegistrationConfig

log = logging.getLogger("avs.scene_memory")

#: observations waiting to be fused at most (the oldest go first when fusion falls behind)
OBS_QUEUE = 8
#: an observation waits for its frame's registration this long at most, s
REGISTRATION_WAIT_S = 2.0
#: the journal's kind of an observation with the odometry correction it was fused with
OBSERVATION_CORRECTED = "observation+correction"


def pack_observation(observation: bytes, correction: np.ndarray | None) -> bytes:
    """An observation's journal payload: its message and the correction it is fused with."""
    T = None if correction is None else np.asarray(correction, float).reshape(-1).tolist()
    return msgpack.packb({"observation": observation, "T_world_odom": T}, use_bin_type=True)


def unpack_observation(payload: bytes) -> tuple[bytes, np.ndarray | None]:
    content = msgpack.unpackb(payload, raw=False)
    T = content["T_world_odom"]
    return content["observation"], None if T is None else np.array(T, float).reshape(4, 4)


def registration_config(s: SceneMemorySettings) -> RegistrationConfig:
    """The registration the settings ask for, weighed against the odometry where they give
    its error (``odometry_noise`` > 0: ``correction_filter``)."""
    a = s.odometry_noise
    m, deg = s.registration_noise
    return RegistrationConfig(
        dof=s.registration_dof,
        odometry_noise=OdometryNoise.share(a) if a > 0 else None,
        registration_noise=RegistrationNoise(m, deg),
    )


def search_config(s: SceneMemorySettings) -> SearchConfig | None:
    """The registration's second stage the settings ask for (None: off)."""
    if not s.registration_search:
        return None
    m, deg = s.registration_search_window
    return SearchConfig(max_correction_m=m, max_correction_deg=deg)


def new_memory(s: SceneMemorySettings) -> SceneMemory:
    return SceneMemory(
        MemoryConfig(
            bounds_min=tuple(s.bounds_min),
            bounds_max=tuple(s.bounds_max),
            fusion=FusionConfig(mode=s.fusion),
            occupancy=OccupancyConfig(voxel=s.voxel, max_range=s.max_range),
            roi=(tuple(s.roi_min), tuple(s.roi_max)) if s.roi_min and s.roi_max else None,
            map_stride=s.map_stride,
            keyframe_move=s.keyframe_move,
            keyframe_turn=s.keyframe_turn,
            registration=registration_config(s) if s.registration else None,
            registration_interval=s.registration_interval,
            search=search_config(s),
        )
    )


class SceneMemoryNode:
    """Two sides, each under a lock of its own, so that neither waits for the other: the map's
    (depth frames: occupancy map, registered cloud, registration; ``map_lock``) and the
    model's (observations: fusion; ``model_lock``). One journal orders both (``journal_lock``):
    an observation's record holds the odometry correction it was fused with, so a replay in
    journal order fuses it as it was fused live, whatever frame was being registered then.
    A snapshot takes both sides' locks (map first) and then the journal's."""

    def __init__(self, node: Node, settings: SceneMemorySettings) -> None:
        self.node, self.settings = node, settings
        self.map_lock = threading.Lock()
        self.model_lock = threading.Lock()
        self.journal_lock = threading.Lock()
        # the seq of the frame being registered (None: none): an observation of that frame or
        # a later one waits for its correction (tens of ms), not for the map's integration
        self.registering: int | None = None
        self.map_seq: int | None = None  # the newest depth frame the map took
        self.registered = threading.Condition()
        # one writer: wait on standby while another instance is active, then restore what
        # it wrote to the shared data directory
        standby = wait_for_turn(node.session, node.keys, "scene_memory", node.instance,
                                lambda: node.stopping)  # fmt: skip
        if standby is None:
            raise SystemExit(0)  # stopped while standing by
        kernels.warm_up(settings.registration)  # before the first frame, not with it
        self.store = Store(settings.data_dir)
        self.replay_s = 0.0  # time the updates since the last snapshot took to apply
        self.snapshot_s = 0.0  # time the last snapshot took to write
        self.writer: threading.Thread | None = None  # the snapshot being written
        self.memory, self.n = self._restore()
        k = node.keys
        self.out_scene = node.publisher(k.scene())
        self.out_correction = node.publisher(k.pose_correction())
        self.out_registered = (
            node.publisher(k.cloud_frame(REGISTERED_CAMERA)) if settings.fusion != "sg" else None
        )
        self.obs_camera = REGISTERED_CAMERA if settings.fusion != "sg" else settings.camera
        # the work runs on the inputs' own threads, never in Zenoh's callbacks, side by side:
        # observations in order (those that waited fused in one turn), depth frames newest
        # first (one at a time). The semantic path first: fusion at nice -5 with perception's
        # worker; the map at BACKGROUND, after rendering, on what the loops and the semantic
        # path leave (newest first, so it never falls behind, it integrates fewer frames):
        # on the kitchen pipeline the map at nice 0 took a quarter of a core from them
        # (frame → semantic model p50 411 ms, at nice 10 321 ms, the same hour)
        node.subscribe(k.observation(), SceneObservation, self.on_observations,
                       queue=OBS_QUEUE, batch=True, nice=FOREGROUND)  # fmt: skip
        node.subscribe(k.rgbd(settings.camera), RgbdFrame, self.on_frame, latest_only=True,
                       nice=BACKGROUND)  # fmt: skip
        node.serve(k.scene(), lambda _r: self.scene())
        node.serve(k.occupancy("stats"), self.on_stats, BoxQuery)
        node.serve(k.occupancy("slice"), self.on_slice, BoxQuery)
        node.serve(k.cloud(), lambda _r: self.cloud())
        node.announce()  # active now: the service's token first, then the standby one goes
        standby.undeclare()

    def _restore(self) -> tuple[SceneMemory, int]:
        state, n, records = self.store.load()
        memory = state if isinstance(state, SceneMemory) else new_memory(self.settings)
        replayed = 0
        for number, kind, payload in records:
            self._apply(memory, kind, payload)
            n, replayed = number, replayed + 1
        if state is not None or replayed:
            log.info(
                "restored",
                extra={
                    "snapshot": state is not None,
                    "journal": replayed,
                    "updates": n,
                    "primitives": len(memory.fusion.prims),
                },
            )
        return memory, n

    @staticmethod
    def _apply(
        memory: SceneMemory,
        kind: str,
        payload: bytes,
        registered: Callable[[], None] | None = None,
        message: RgbdFrame | SceneObservation | None = None,
    ) -> None:
        """Apply a journal record; ``message``: its message, already decoded (live, where the
        node has it: not decoded again from the bytes just journaled)."""
        if kind == "frame":
            memory.integrate(
                message if message is not None else decode(payload, RgbdFrame), registered
            )
        elif kind == "skip":
            memory.skip()
        elif kind == OBSERVATION_CORRECTED:
            obs, correction = unpack_observation(payload)
            memory.fuse(
                message if message is not None else decode(obs, SceneObservation), correction
            )
        else:  # "observation": journaled before corrections were (the last one's then)
            memory.fuse(decode(payload, SceneObservation))

    def _update(self, kind: str, message) -> None:
        payload = encode(message) if message is not None else b""
        with self.map_lock:
            # observations of this frame or later wait for its registration only where it is
            # registered (every registration_interval): otherwise the correction they take is
            # the one in force already
            if kind == "frame" and self.memory.will_register(message):
                with self.registered:
                    self.registering = message.seq
            try:
                due = self._apply_update(kind, payload, self._registered, message)
            finally:
                self._registered()
        if due:
            self._snapshot()

    def _registered(self) -> None:
        """The frame in flight has its pose: observations waiting for it go on."""
        with self.registered:
            self.registering = None
            self.registered.notify_all()

    def _apply_update(
        self,
        kind: str,
        payload: bytes,
        registered: Callable[[], None] | None = None,
        message: RgbdFrame | SceneObservation | None = None,
    ) -> bool:
        """Journal and apply (the caller holds its side's lock); whether a snapshot is due
        (the caller takes it once it let its lock go: ``_snapshot``)."""
        with self.journal_lock:
            self.n += 1
            n = self.n
            self.store.append(n, kind, payload)  # journaled before it is applied
        t0 = time.perf_counter()
        self._apply(self.memory, kind, payload, registered, message)
        for key, value in dict(self.memory.timings_ms).items():
            self.node.metrics.gauge(key, value)
        s = self.settings
        with self.journal_lock:
            self.replay_s += time.perf_counter() - t0
            return snapshot_due(n, self.replay_s, self.snapshot_s, s.snapshot_every,
                                s.max_replay_s, s.snapshot_share)  # fmt: skip

    def _snapshot(self) -> None:
        """Capture the state with every lock held (map, model, journal: nothing in flight,
        every journaled update applied; tens of ms) and write it on a thread of its own
        (serialising and writing a kitchen map take 0.2-0.4 s, during which frames and
        observations go on). Called with neither side's lock held; none while one is being
        written."""
        with self.map_lock, self.model_lock, self.journal_lock:
            if self.writer is not None and self.writer.is_alive():
                return
            self._capture()

    def _capture(self) -> None:
        t0 = time.perf_counter()
        finish = self.store.begin_snapshot(self.memory, self.n)
        captured = time.perf_counter() - t0
        self.replay_s = 0.0

        def write() -> None:
            t1 = time.perf_counter()
            finish()
            self.snapshot_s = captured + time.perf_counter() - t1
            self.node.metrics.gauge("snapshot_ms", self.snapshot_s * 1e3)
            self.node.metrics.gauge("snapshot_capture_ms", captured * 1e3)

        self.writer = threading.Thread(target=write, name="scene_memory:snapshot", daemon=True)
        self.writer.start()

    def on_frame(self, frame: RgbdFrame) -> None:
        key = self.node.keys.rgbd(frame.camera)
        frame = usable_depth_frame(self.node, key, frame, self.settings.max_pixels)
        if frame is None:
            return
        if self.memory.is_keyframe(frame.T_world_camera):
            self._update("frame", frame)
            if self.settings.registration:
                self.out_correction.put(self.correction(frame))
        else:
            self._update("skip", None)
            self.node.metrics.gauge("frames_skipped", self.memory.frames_skipped)
        self.map_seq = frame.seq  # the newest frame the map took (OccupancyStats.frame_seq)
        if self.out_registered is not None:
            with self.map_lock:
                cloud = registered_cloud(self.memory, frame)
            self.out_registered.put(cloud)

    def on_observation(self, obs: SceneObservation) -> None:
        self.on_observations([obs])

    def on_observations(self, observations: list[SceneObservation]) -> None:
        """Fuse the observations that waited, in order, each journaled with its correction;
        then publish one scene model for all of them (``fused_frames``): when fusion falls
        behind, the model (its build, encoding and sending: a third of an observation's cost
        in a kitchen) is made once for what waited, not once each, so that it catches up."""
        fused, due = [], False
        for obs in observations:
            if obs.camera != self.obs_camera:
                continue  # pc fusion takes the registered cloud's observations only
            # its own frame's correction when that frame is being registered (the observation
            # was perceived at that frame's odometry pose), not the one before it by a race
            with self.registered:
                self.registered.wait_for(
                    lambda o=obs: self.registering is None or self.registering > o.frame_seq,
                    timeout=REGISTRATION_WAIT_S,
                )
            with self.model_lock:
                # the correction the map's side has now (a reference read: it replaces the
                # array, never writes into it), journaled with the observation it moves
                payload = pack_observation(encode(obs), self.memory.T_world_odom)
                due = self._apply_update(OBSERVATION_CORRECTED, payload, message=obs) or due
            fused.append(obs.frame_seq)
        if not fused:
            return
        with self.model_lock:  # the model as of the last of them
            scene = self.memory.scene(self.n, float(self.n), fused)
        self.node.metrics.gauge("observations_per_model", len(fused))
        self.out_scene.put(scene)
        if due:
            self._snapshot()

    def correction(self, frame: RgbdFrame) -> PoseCorrection:
        """What registering ``frame`` found (the first frame starts the map: identity)."""
        with self.map_lock:
            m = self.memory
            last = m.last_registration or {"accepted": True, "reason": "", "fitness": 1.0,
                                           "rmse": 0.0, "ms": 0.0}  # fmt: skip
            T = m.T_world_odom if m.T_world_odom is not None else np.eye(4)
            refused, not_due = m.registrations_refused, m.registrations_not_due
        self.node.metrics.gauge("registrations_refused", refused)
        self.node.metrics.gauge("registrations_not_due", not_due)
        rmse = last["rmse"] if math.isfinite(last["rmse"]) else 0.0
        return PoseCorrection(
            seq=frame.seq, stamp=frame.stamp, T_world_odom=T, camera=frame.camera,
            frame_seq=frame.seq, accepted=last["accepted"], reason=last["reason"],
            fitness=last["fitness"], rmse=rmse, registration_ms=last["ms"], refused=refused,
        )  # fmt: skip

    def scene(self) -> SceneModel:
        with self.model_lock:
            return self.memory.scene(self.n, float(self.n))

    def _box(self, request: BoxQuery | None) -> tuple[np.ndarray, np.ndarray]:
        if request is not None:
            return request.box_min, request.box_max
        s, occ = self.settings, self.memory.occupancy
        if s.roi_min and s.roi_max:
            return np.array(s.roi_min), np.array(s.roi_max)
        return occ.lo, occ.hi

    def on_stats(self, request: BoxQuery | None) -> OccupancyStats:
        lo, hi = self._box(request)
        with self.map_lock:
            occ = self.memory.occupancy
            unknown, free, occupied = occ.counts(lo, hi)
            realised = self.memory.realised_gain
            return OccupancyStats(
                seq=self.n,
                voxel_size=occ.voxel,
                box_min=lo,
                box_max=hi,
                unknown=unknown,
                free=free,
                occupied=occupied,
                map_version=occ.version,
                frames_integrated=occ.frames,
                frames_skipped=self.memory.frames_skipped,
                frame_seq=self.map_seq,
                realised_volume=int(realised["volume"]),
                realised_rays=realised["rays"],
            )

    def on_slice(self, request: BoxQuery | None) -> Iterator[OccupancySlice]:
        """The voxel states in the box (default: the roi, else the map), in pages of at most
        ``slice_page_voxels`` (slabs along x): no reply grows with the box asked for."""
        lo, hi = self._box(request)
        with self.map_lock:
            occ = self.memory.occupancy
            x0, y0, z0, x1, y1, z1 = occ.index_box(lo, hi)
            per_x = max(1, (y1 - y0) * (z1 - z0))
            slab = max(1, self.settings.slice_page_voxels // per_x)
            starts = list(range(x0, max(x1, x0 + 1), slab))
            # one seq for every page: the fusion counts updates on its own thread meanwhile
            # (live, the pages of one map came with several seqs and could not be joined)
            n = self.n
            for page, a in enumerate(starts):
                origin, states = occ.states_in((a, y0, z0, min(a + slab, x1), y1, z1))
                yield OccupancySlice(
                    seq=n,
                    voxel_size=occ.voxel,
                    origin=origin,
                    states=states,
                    map_version=occ.version,
                    page=page,
                    pages=len(starts),
                )

    def cloud(self) -> PointCloud:
        with self.map_lock:
            return self.memory.point_cloud(self.n)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.join()  # the snapshot in flight finished, not cut short
        self.store.close()
