"""The adapter's thin node: librealsense's callback hands framesets to a latest-only slot and
publishes IMU samples; one worker thread aligns depth to colour, converts and publishes
``sensors/rgbd/<camera>``. A playback stops the node when the recording ends."""

from __future__ import annotations

import logging
import threading
import time
from types import ModuleType
from typing import Any, Generic, TypeVar

import numpy as np

from schemas import ImuSample
from services.adapters.realsense import core
from services.adapters.realsense.config import RealsenseSettings
from services.adapters.realsense.device import (
    RealsenseError,
    import_rs,
    resolvable_config,
    stream_facts,
)
from services.common.node import Node

T = TypeVar("T")

#: accelerometer readings averaged to check the configured pitch and roll against gravity
TILT_READINGS = 50
#: disagreement between the configured tilt and the IMU's that is worth a warning, degrees
TILT_WARN_DEG = 5.0

log = logging.getLogger("avs.realsense")


class LatestSlot(Generic[T]):
    """Holds one item, the newest: ``put`` replaces what was not taken yet, ``take`` waits."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._item: T | None = None

    def put(self, item: T) -> bool:
        """Store ``item``; True when it replaced one that nobody took (a dropped frame)."""
        with self._cond:
            replaced = self._item is not None
            self._item = item
            self._cond.notify()
            return replaced

    def take(self, timeout: float) -> T | None:
        """The newest item (and empty the slot), or None after ``timeout`` seconds."""
        with self._cond:
            if self._item is None:
                self._cond.wait(timeout)
            item, self._item = self._item, None
            return item


class RealsenseNode:
    """Streams one RealSense (or a recording of one) onto the node's keys until closed."""

    def __init__(self, node: Node, settings: RealsenseSettings, rs: ModuleType | None = None):
        self.rs = rs if rs is not None else import_rs()
        self.node, self.settings = node, settings
        s = settings
        self.out_frames = node.publisher(node.keys.rgbd(s.camera))
        self.out_imu = node.publisher(node.keys.imu())
        self.T_world_camera = core.T_world_camera(s.x, s.y, s.z, s.yaw, s.pitch, s.roll)
        self.slot: LatestSlot[Any] = LatestSlot()
        self.pairing = core.ImuPairing()
        self.align = self.rs.align(self.rs.stream.color)
        self._ready = threading.Event()
        self._seq_frames = self._seq_imu = 0
        self._accel_readings: list[np.ndarray] = []
        self._closing = False

        self.pipeline = self.rs.pipeline()
        config, imu = resolvable_config(self.rs, self.pipeline, s)
        if s.playback is not None:
            self._wait_for_subscriber(s.playback_wait)
        try:
            profile = self.pipeline.start(config, self._on_frames)
        except RuntimeError as e:
            raise RealsenseError(f"the RealSense pipeline did not start: {e}") from e
        try:
            self.facts = stream_facts(self.rs, profile, imu)
            self.playback = profile.get_device().as_playback() if s.playback else None
        except Exception:
            self._closing = True
            self._ready.set()
            self.pipeline.stop()
            raise
        R_colour_imu = self.facts.R_colour_imu
        if imu and R_colour_imu is None:
            log.warning("the device names no IMU-to-colour extrinsics: taking the IMU's axes "
                        "as the colour camera's")  # fmt: skip
        self.R_colour_imu = np.eye(3) if R_colour_imu is None else R_colour_imu
        self.imu_orientation = core.quaternion(self.T_world_camera[:3, :3] @ self.R_colour_imu)
        if self.facts.distorted:
            log.warning("the colour stream has lens distortion; frames carry pinhole intrinsics")
        log.info(
            "streaming",
            extra={
                "device": self.facts.device,
                "serial": self.facts.serial,
                "playback": str(s.playback) if s.playback else None,
                "depth_scale": self.facts.depth_scale,
                "intrinsics": self.facts.intrinsics.model_dump(),
                "imu": imu,
                "key": self.out_frames.key,
            },
        )
        self._worker = threading.Thread(target=self._work, name="realsense-frames", daemon=True)
        self._worker.start()
        self._ready.set()

    # -- librealsense's callback thread(s): nothing heavy here --------------------------------

    def _on_frames(self, frame: Any) -> None:
        if not self._ready.wait(10.0) or self._closing:
            return
        try:
            if frame.is_frameset():
                frames = frame.as_frameset()
                if frames.get_depth_frame() and frames.get_color_frame():
                    frames.keep()
                    if self.slot.put(frames):
                        self.node.metrics.drop_n("superseded", 1)
                for member in frames:
                    if member.is_motion_frame():
                        self._on_motion(member.as_motion_frame())
            elif frame.is_motion_frame():
                self._on_motion(frame.as_motion_frame())
        except Exception as e:
            self.node.drop(f"callback_error:{type(e).__name__}", "realsense", repr(e))

    def _on_motion(self, motion: Any) -> None:
        v = motion.get_motion_data()
        xyz = (v.x, v.y, v.z)
        kind = motion.get_profile().stream_type()
        if kind == self.rs.stream.accel:
            self.pairing.accel(xyz)
            self._check_tilt(xyz)
            return
        if kind != self.rs.stream.gyro:
            return
        sample = self.pairing.gyro(motion.get_timestamp() / 1e3, xyz)
        if sample is None:
            return
        self.out_imu.put_fields(
            ImuSample,
            seq=self._seq_imu,
            stamp=sample.stamp,
            frame=self.settings.imu_frame,
            angular_velocity=sample.angular_velocity,
            linear_acceleration=sample.linear_acceleration,
            orientation=self.imu_orientation,
        )
        self._seq_imu += 1

    def _check_tilt(self, xyz: tuple[float, float, float]) -> None:
        """Once, after the first readings: does gravity agree with the configured pose?"""
        if len(self._accel_readings) >= TILT_READINGS:
            return
        self._accel_readings.append(self.R_colour_imu @ np.asarray(xyz, float))
        if len(self._accel_readings) < TILT_READINGS:
            return
        pitch, roll = core.gravity_tilt(np.mean(self._accel_readings, axis=0))
        s = self.settings
        off = max(abs(pitch - s.pitch), abs((roll - s.roll + 180) % 360 - 180))
        (log.warning if off > TILT_WARN_DEG else log.info)(
            "gravity says the camera is pitched %.1f° down and rolled %.1f° (configured: "
            "--pitch %.1f --roll %.1f; frames are placed by the configured pose)",
            pitch, roll, s.pitch, s.roll,
        )  # fmt: skip

    # -- the worker ---------------------------------------------------------------------------

    def _work(self) -> None:
        while not (self._closing or self.node.stopping):
            frames = self.slot.take(0.2)
            if frames is None:
                if self._playback_ended():
                    self._finish()
                    return
                continue
            t0 = time.perf_counter()
            try:
                message = self._frame(frames)
            except Exception as e:
                self.node.drop(f"frame_error:{type(e).__name__}", self.out_frames.key, repr(e))
                continue
            finally:
                del frames
            self.node.metrics.record("frame", time.perf_counter() - t0)
            self.out_frames.put(message)
            self._seq_frames += 1

    def _frame(self, frames: Any):
        """Align depth to colour and convert: the wire frame of one frameset."""
        aligned = self.align.process(frames)
        depth, colour = aligned.get_depth_frame(), aligned.get_color_frame()
        s = self.settings
        return core.rgbd_frame(
            seq=self._seq_frames,
            stamp=colour.get_timestamp() / 1e3,
            camera=s.camera,
            intrinsics=self.facts.intrinsics,
            rgb=core.to_rgb(np.asanyarray(colour.get_data()), self.facts.colour_format),
            depth=core.depth_metres(
                np.asanyarray(depth.get_data()), self.facts.depth_scale, s.depth_min, s.depth_max
            ),
            T_world_camera=self.T_world_camera,
            depth_min=s.depth_min,
            depth_max=s.depth_max,
        )

    def _playback_ended(self) -> bool:
        return (
            self.playback is not None
            and self.playback.current_status() == self.rs.playback_status.stopped
        )

    def _finish(self) -> None:
        log.info("playback ended", extra={"frames": self._seq_frames, "imu": self._seq_imu})
        self.node.spin(self.settings.playback_linger)  # let the last messages leave
        self.node.stop()

    def _wait_for_subscriber(self, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not self.out_frames.matched and time.monotonic() < deadline:
            time.sleep(0.05)

    def close(self) -> None:
        """Stop the pipeline (no more callbacks), then the worker."""
        self._closing = True
        try:
            self.pipeline.stop()
        except RuntimeError:
            log.debug("pipeline already stopped", exc_info=True)
        if self._worker is not threading.current_thread():
            self._worker.join(timeout=5.0)
