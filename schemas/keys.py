"""Key expressions of SPEC §1, under ``avs/<robot>/``, and the quality of service of each.

``Keys("armar6").rgbd("head_rgbd") == "avs/armar6/sensors/rgbd/head_rgbd"``. ``KEY_TABLE`` is
the table itself: what travels on each key, its kind, who produces it, and how it is sent.
QoS is given as plain strings so this module needs no Zenoh; the runtime maps them.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal

DEFAULT_ROBOT = "armar6"
PREFIX = "avs"

_CHUNK = re.compile(r"^[A-Za-z0-9_\-.]+$")

KeyKind = Literal["stream", "command", "queryable", "liveliness"]
Congestion = Literal["drop", "block"]
Priority = Literal[
    "real_time", "interactive_high", "interactive_low", "data_high", "data", "data_low"
]


def check_chunk(value: str, what: str) -> str:
    """A single key chunk: letters, digits, ``_ - .``; no ``/``, wildcards or ``$``."""
    if not _CHUNK.match(value):
        raise ValueError(f"{what} {value!r} is not a valid key chunk (letters, digits, _ - .)")
    return value


@dataclass(frozen=True)
class KeySpec:
    """One row of the key table. ``pattern`` is relative to ``avs/<robot>/``."""

    pattern: str
    schemas: tuple[str, ...]
    kind: KeyKind
    producer: str
    congestion: Congestion = "drop"
    priority: Priority = "data"
    express: bool = False
    note: str = ""


# fmt: off
KEY_TABLE: tuple[KeySpec, ...] = (
    KeySpec("sensors/rgbd/*", ("RgbdFrame",), "stream", "sim", "block", "data", False, "5-30 Hz"),
    KeySpec("sensors/cloud/*", ("CloudFrame",), "stream", "scene_memory", "block", "data", False, "per integrated frame (pc, pc+sg fusion)"),
    KeySpec("sensors/imu", ("ImuSample",), "stream", "sim", "drop", "real_time", True, "500-1000 Hz"),
    KeySpec("state/joints", ("JointState",), "stream", "sim", "drop", "interactive_high", True, "500-1000 Hz"),
    KeySpec("state/base", ("BasePose",), "stream", "sim", "drop", "interactive_high", True, "100 Hz"),
    KeySpec("cmd/base", ("BaseGoal", "BaseVelocity"), "command", "nbv", "block", "interactive_high", False, "on demand"),
    KeySpec("cmd/head", ("HeadCommand",), "command", "gaze", "drop", "real_time", True, "up to 1 kHz"),
    KeySpec("cmd/arm", ("ArmCommand",), "command", "grasp servo", "drop", "real_time", True, "up to 1 kHz"),
    KeySpec("perception/observation", ("SceneObservation",), "stream", "perception", "block", "data", False, "per processed frame"),
    KeySpec("memory/scene", ("SceneModel",), "stream", "scene_memory", "block", "data", False, "put on change + queryable"),
    KeySpec("memory/occupancy/**", ("OccupancyStats", "OccupancySlice"), "queryable", "scene_memory", note="queryable"),
    KeySpec("memory/cloud", ("PointCloud",), "queryable", "scene_memory", note="queryable"),
    KeySpec("memory/pose_correction", ("PoseCorrection",), "stream", "scene_memory", "block", "data", False, "per integrated frame (registration on)"),
    KeySpec("nbv/candidates", ("ViewCandidates",), "stream", "nbv", "block", "data", False, "per planning step"),
    KeySpec("nbv/next_view", ("NextBestView",), "stream", "nbv", "block", "interactive_low", False, "per planning step"),
    KeySpec("nbv/plan", ("PlanRequest", "NextBestView"), "queryable", "nbv", note="queryable"),
    KeySpec("nbv/gain/*", ("GainRequest", "Gains"), "queryable", "nbv", note="queryable: a share of the candidates"),
    KeySpec("gaze/target", ("GazeTarget",), "command", "nbv", "block", "interactive_high", False, "on demand"),
    KeySpec("gaze/egosphere", ("EgoSphereSnapshot",), "stream", "gaze", "drop", "data_low", False, "2-10 Hz"),
    KeySpec("explore/status", ("ExploreStatus",), "stream", "explorer", "block", "interactive_low", False, "on change"),
    KeySpec("explore/control", ("ExploreControl", "ExploreStatus"), "queryable", "explorer", note="queryable, operator only"),
    KeySpec("sim/ground_truth", ("GroundTruthQuery", "GroundTruth"), "queryable", "sim", note="queryable"),
    KeySpec("sim/control", ("SimControl", "SimStatus"), "queryable", "sim", note="queryable"),
    KeySpec("alive/*/*", (), "liveliness", "every service", note="liveliness token"),
    KeySpec("metrics/*/*", ("ServiceMetrics",), "queryable", "every service", note="queryable"),
    KeySpec("supervisor", ("SupervisorStatus",), "queryable", "avs up", note="queryable: the services it keeps running"),
)
# fmt: on


def _matches(pattern: str, relative: str) -> bool:
    p, r = pattern.split("/"), relative.split("/")
    if p and p[-1] == "**":
        return len(r) >= len(p) - 1 and all(a in ("*", b) for a, b in zip(p[:-1], r, strict=False))
    return len(p) == len(r) and all(a in ("*", b) for a, b in zip(p, r, strict=True))


@dataclass(frozen=True)
class Keys:
    """Builders for the keys of one robot."""

    robot: str = DEFAULT_ROBOT

    def __post_init__(self) -> None:
        check_chunk(self.robot, "robot name")

    @property
    def prefix(self) -> str:
        return f"{PREFIX}/{self.robot}"

    def key(self, relative: str) -> str:
        return f"{self.prefix}/{relative}"

    def rgbd(self, camera: str = "*") -> str:
        return self.key(f"sensors/rgbd/{self._chunk_or_star(camera)}")

    def cloud_frame(self, camera: str = "*") -> str:
        return self.key(f"sensors/cloud/{self._chunk_or_star(camera)}")

    def imu(self) -> str:
        return self.key("sensors/imu")

    def joints(self) -> str:
        return self.key("state/joints")

    def base_state(self) -> str:
        return self.key("state/base")

    def cmd_base(self) -> str:
        return self.key("cmd/base")

    def cmd_head(self) -> str:
        return self.key("cmd/head")

    def cmd_arm(self) -> str:
        return self.key("cmd/arm")

    def observation(self) -> str:
        return self.key("perception/observation")

    def scene(self) -> str:
        return self.key("memory/scene")

    def occupancy(self, what: str = "stats") -> str:
        return self.key(f"memory/occupancy/{check_chunk(what, 'occupancy query')}")

    def cloud(self) -> str:
        return self.key("memory/cloud")

    def pose_correction(self) -> str:
        return self.key("memory/pose_correction")

    def candidates(self) -> str:
        return self.key("nbv/candidates")

    def next_view(self) -> str:
        return self.key("nbv/next_view")

    def plan(self) -> str:
        return self.key("nbv/plan")

    def gain(self, instance: str = "*") -> str:
        return self.key(f"nbv/gain/{self._chunk_or_star(instance)}")

    def gaze_target(self) -> str:
        return self.key("gaze/target")

    def egosphere(self) -> str:
        return self.key("gaze/egosphere")

    def explore_status(self) -> str:
        return self.key("explore/status")

    def explore_control(self) -> str:
        return self.key("explore/control")

    def ground_truth(self) -> str:
        return self.key("sim/ground_truth")

    def sim_control(self) -> str:
        return self.key("sim/control")

    def alive(self, service: str = "*", instance: str = "*") -> str:
        return self.key(f"alive/{self._chunk_or_star(service)}/{self._chunk_or_star(instance)}")

    def metrics(self, service: str = "*", instance: str = "*") -> str:
        return self.key(f"metrics/{self._chunk_or_star(service)}/{self._chunk_or_star(instance)}")

    def supervisor(self) -> str:
        return self.key("supervisor")

    @staticmethod
    def _chunk_or_star(value: str) -> str:
        return value if value == "*" else check_chunk(value, "name")

    def relative(self, key: str) -> str | None:
        """``key`` without ``avs/<robot>/``, or None when it is not this robot's key."""
        head = self.prefix + "/"
        return key[len(head) :] if key.startswith(head) else None


def spec_for(key: str) -> KeySpec | None:
    """The table row of a concrete key ``avs/<robot>/...``, if any."""
    parts = key.split("/", 2)
    if len(parts) < 3 or parts[0] != PREFIX:
        return None
    return next((s for s in KEY_TABLE if _matches(s.pattern, parts[2])), None)
