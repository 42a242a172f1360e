"""The perception node: RGB-D frames in, one SceneObservation per frame out.

Workers share the stream: every instance sees every frame, and the one that owns it by
rendezvous hashing of (camera, seq) over the live instances' liveliness tokens processes it
(services/common/membership.py); the others skip it. An instance joining or leaving moves only
the frames it wins or held. Each worker keeps at most ``queue`` of its frames waiting: when it
falls behind, the oldest is dropped as stale, counted, so it never works on old frames.
With ``max_rate`` a worker perceives at most that many frames a second (``avs up`` runs it at
6: at 15 fps it and the fusion of its observations would leave the map no time on 2 cores),
each the first to arrive once its time has come (``pacing.py``: not the newest waiting one,
which could be a camera period old); a newer frame replaces a waiting one, which is counted as
dropped for ``rate`` (by design: no warning). A frame without depth, or larger than
``max_pixels``, is dropped and counted; an empty or all-invalid frame gives an observation
with no primitives. Observations carry the worker.
A frame that carries the robot's joint positions has the robot's own body masked out first
(``self_mask.py``), so the robot never perceives its arms and hands as scene primitives.

World clouds of the camera (``sensors/cloud/<camera>``, CloudFrame: the scene memory's
registered cloud in ``pc`` / ``pc+sg`` fusion, with ``--camera registered``) are perceived
the same way, shared and queued with the frames, by the point-set pipeline
(``Perception.perceive_points``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque

import numpy as np

from schemas import CloudFrame, RgbdFrame
from schemas.codec import peek
from services.common.frames import usable_depth_frame
from services.common.membership import Members
from services.common.node import Node
from services.common.realtime import foreground
from services.common.robots import robot_mjcf
from services.perception.config import PerceptionSettings
from services.perception.pacing import Pacer
from services.perception.pipeline import (
    Perception,
    PerceptionConfig,
    cloud_observation,
    observation,
)
from services.perception.self_mask import RobotBody

log = logging.getLogger("avs.perception")


class PerceptionNode:
    def __init__(self, node: Node, settings: PerceptionSettings) -> None:
        self.node, self.settings = node, settings
        self.perception = Perception(
            PerceptionConfig(
                depth_min=settings.depth_min,
                depth_max=settings.depth_max,
                stride=settings.stride,
                smooth_per_m2=settings.smooth_per_m2,
                seed=settings.seed,
            )
        )
        self.perception.warm_up()
        self.out = node.publisher(node.keys.observation())
        self.seq = 0
        self.key = node.keys.rgbd(settings.camera)
        self.members = Members(node.session, node.keys.alive("perception"), node.instance)
        self.cloud_key = node.keys.cloud_frame(settings.camera)
        self.pending: deque[tuple[float, RgbdFrame | CloudFrame]] = deque()  # (arrival, frame)
        self.pacer = Pacer(settings.max_rate) if settings.max_rate > 0 else None
        self.ready = threading.Condition()
        self.skipped = 0
        self.body: RobotBody | None = None
        node.subscribe(self.key, RgbdFrame, self.on_arrival, name="on_arrival", accept=self.mine)
        node.subscribe(self.cloud_key, CloudFrame, self.on_arrival, name="on_cloud",
                       accept=self.mine)  # fmt: skip
        node.start_thread(self.work, "perception:work")

    def mine(self, payload: bytes) -> bool:
        """Whether this worker owns the frame, from its first bytes (another worker's frame is
        not even decoded). A frame whose header cannot be read is decoded, and judged there."""
        head = peek(payload, "camera", "seq")
        if len(head) < 2 or self.members.owns(f"{head['camera']}:{head['seq']}"):
            return True
        self.skipped += 1
        self.node.metrics.gauge("frames_of_others", self.skipped)
        return False

    def on_arrival(self, frame: RgbdFrame | CloudFrame) -> None:
        """Queue a frame of this worker's."""
        if not self.members.owns(f"{frame.camera}:{frame.seq}"):
            return
        arrived = time.monotonic()
        with self.ready:
            if self.pacer is not None:  # only the newest is ever taken: it replaces the rest
                self.pacer.arrived(arrived)
                while self.pending:
                    self.pending.popleft()
                    self.node.metrics.drop("rate")
            elif len(self.pending) >= self.settings.queue:
                _, stale = self.pending.popleft()
                self.node.drop("stale", self.key, f"frame {stale.seq} waited too long")
            self.pending.append((arrived, frame))
            self.ready.notify()

    def work(self) -> None:
        if self.settings.realtime:
            foreground("perception's worker")
        pacer = self.pacer
        while not self.node.stopping:
            if pacer is not None:  # at most max_rate frames a second: wait for the next slot
                time.sleep(max(0.0, pacer.slot - time.monotonic()))
            with self.ready:
                if pacer is not None:  # the first frame from the slot on, if one comes soon
                    deadline = time.monotonic() + pacer.patience()
                    while not (self.pending and pacer.fresh(self.pending[-1][0])):
                        left = deadline - time.monotonic()
                        if left <= 0 or self.node.stopping:
                            break
                        self.ready.wait(left)
                if not self.pending and not self.ready.wait(0.2):
                    continue
                _, frame = self.pending.popleft()
            if pacer is not None:
                pacer.took(time.monotonic())
            is_cloud = isinstance(frame, CloudFrame)
            try:
                self.on_cloud(frame) if is_cloud else self.on_frame(frame)
            except Exception as e:  # a bad frame never stops the worker
                key = self.cloud_key if is_cloud else self.key
                self.node.drop(f"handler_error:{type(e).__name__}", key, repr(e))

    def close(self) -> None:
        self.members.close()

    def own_body(self, frame: RgbdFrame) -> np.ndarray | None:
        """The pixels of the robot's own body in the frame, from the joint positions it
        carries (None: no joints, self-masking off, or a robot without a model here)."""
        if not self.settings.self_mask or not frame.joint_names or frame.depth is None:
            return None
        if self.body is None:
            try:
                self.body = RobotBody(robot_mjcf(self.node.keys.robot),
                                      self.settings.self_mask_margin)  # fmt: skip
            except FileNotFoundError as e:
                self.settings.self_mask = False
                log.warning("not masking the robot's own body: %s", e)
                return None
        K = frame.intrinsics
        joints = dict(zip(frame.joint_names, frame.joint_positions.tolist(), strict=True))
        try:
            mask = self.body.mask(frame.depth, K.fx, K.fy, K.cx, K.cy, frame.camera, joints)
        except KeyError:  # a camera the robot's model does not have (a replayed recording)
            return None
        self.node.metrics.gauge("self_masked_px", int(mask.sum()))
        return mask

    def on_frame(self, frame: RgbdFrame) -> None:
        frame = usable_depth_frame(self.node, self.key, frame, self.settings.max_pixels)
        if frame is None:
            return
        result = self.perception.perceive(
            frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera, self.own_body(frame)
        )
        c = self.perception.config
        self.out.put(
            observation(result, frame, self.seq, self.node.instance, c.depth_max, c.stride)
        )
        self._done(result)

    def on_cloud(self, cloud: CloudFrame) -> None:
        """A world cloud (the registered cloud of the roi): the point-set pipeline."""
        result = self.perception.perceive_points(
            cloud.points, cloud.viewpoints, cloud.colours, cloud.T_world_camera[:3, 3]
        )
        self.out.put(cloud_observation(result, cloud, self.seq, self.node.instance))
        self._done(result)

    def _done(self, result) -> None:
        self.seq += 1
        self.node.metrics.gauge("frames_done", self.seq)
        self.node.metrics.gauge("workers", len(self.members.current()))
        self.node.metrics.gauge("primitives", len(result.primitives))
        self.node.metrics.gauge("total_ms", result.timings_ms["total"])
