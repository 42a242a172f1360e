"""The wire contract of AVS: message models, the msgpack codec and the key expressions.

Services share nothing but this package and the small common runtime. Every message is a
pydantic model; ``encode`` / ``decode`` put it on and take it off the wire; ``Keys`` builds the
key expressions of SPEC §1.
"""

from schemas.base import REGISTRY, Message, Model, Stamped
from schemas.codec import ERROR_KINDS, CodecError, decode, encode, encode_fields
from schemas.commands import ArmCommand, BaseGoal, BaseVelocity, HeadCommand
from schemas.explore import ExploreControl, ExploreStatus
from schemas.gaze import EgoSphereSnapshot, GazeTarget
from schemas.keys import DEFAULT_ROBOT, KEY_TABLE, Keys, KeySpec, spec_for
from schemas.occupancy import BoxQuery, OccupancySlice, OccupancyStats
from schemas.planning import GainRequest, Gains, NextBestView, PlanRequest, ViewCandidates
from schemas.runtime import (
    QueryError,
    ServiceMetrics,
    SupervisedService,
    SupervisorStatus,
    TimingSummary,
)
from schemas.scene import (
    Affordance,
    BoxModel,
    CylinderModel,
    Obb,
    PlaneModel,
    PointCloud,
    PoseCorrection,
    Primitive,
    SceneGraph,
    SceneModel,
    SceneObservation,
    SpatialEdge,
    SphereModel,
    SupportEdge,
)
from schemas.sensors import (
    BasePose,
    CameraIntrinsics,
    CloudFrame,
    ImuSample,
    JointState,
    RgbdFrame,
)
from schemas.sim import GroundTruth, GroundTruthObject, GroundTruthQuery, SimControl, SimStatus

__all__ = [
    "DEFAULT_ROBOT",
    "ERROR_KINDS",
    "KEY_TABLE",
    "REGISTRY",
    "Affordance",
    "ArmCommand",
    "BaseGoal",
    "BasePose",
    "BaseVelocity",
    "BoxModel",
    "BoxQuery",
    "CameraIntrinsics",
    "CloudFrame",
    "CodecError",
    "CylinderModel",
    "EgoSphereSnapshot",
    "ExploreControl",
    "ExploreStatus",
    "GainRequest",
    "Gains",
    "GazeTarget",
    "GroundTruth",
    "GroundTruthObject",
    "GroundTruthQuery",
    "HeadCommand",
    "ImuSample",
    "JointState",
    "KeySpec",
    "Keys",
    "Message",
    "Model",
    "NextBestView",
    "Obb",
    "OccupancySlice",
    "OccupancyStats",
    "PlanRequest",
    "PlaneModel",
    "PointCloud",
    "PoseCorrection",
    "Primitive",
    "QueryError",
    "RgbdFrame",
    "SceneGraph",
    "SceneModel",
    "SceneObservation",
    "ServiceMetrics",
    "SimControl",
    "SimStatus",
    "SpatialEdge",
    "SphereModel",
    "Stamped",
    "SupervisedService",
    "SupervisorStatus",
    "SupportEdge",
    "TimingSummary",
    "ViewCandidates",
    "decode",
    "encode",
    "encode_fields",
    "spec_for",
]
