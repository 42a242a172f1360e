"""Settings of the gaze service (env AVS_GAZE_<FIELD> or --flag)."""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from services.common.config import ServiceSettings

#: the cameras that fixate by default, per robot
FIXATING = {"armar3": ["left_foveal", "right_foveal"], "armar6": ["head_rgbd"]}


class GazeSettings(ServiceSettings):
    """Ego-sphere view selection and the gaze stabiliser (thesis Ch. 5)."""

    SERVICE: ClassVar[str] = "gaze"

    cameras: list[str] = Field(
        default_factory=list,
        description="cameras whose optical axes hold the fixation point (default: per robot)",
    )
    gain: float = Field(20.0, gt=0, description="K: feedback on the fixation error, 1/s")
    damping: float = Field(0.02, ge=0, description="λ of the damped least squares")
    eye_weight: float = Field(8.0, gt=0, description="eye joints' weight, the neck's being 1")
    vor_gain: float = Field(1.0, ge=0, description="VOR: share of the unpredicted rotation")
    okr_gain: float = Field(1.0, ge=0, description="OKR: share of the retinal slip taken (0: off)")
    okr_camera: str = Field(
        "", description="camera whose frames give the retinal slip (default: the first fixating)"
    )
    odometry: bool = Field(True, description="feed the platform's odometry forward")
    stale_ms: float = Field(
        50.0, gt=0, description="an input older than this holds the head still (ms)"
    )
    blob_camera: str = Field(
        "", description="camera whose frames give colour blobs for the ego-sphere ('' = none)"
    )
    blob_saliency: float = Field(0.5, ge=0, description="saliency of a colour blob")
    points: int = Field(40_000, ge=100, description="ego-sphere points")
    expiry: float = Field(5.0, gt=0, description="saliency values expire after this, s")
    select_every: float = Field(2.0, gt=0, description="s between ego-sphere selections")
    egosphere_rate: float = Field(2.0, ge=0, description="gaze/egosphere snapshots per second")
    egosphere_every: int = Field(20, ge=1, description="snapshot: every n-th point")
    acuity: float = Field(0.01, gt=0, description="α: the object localisation the task needs, m")
    realtime: bool = Field(
        True, description="real-time scheduling (SCHED_RR, else nice -10) where permitted"
    )
    cpus: list[int] = Field(
        default_factory=list,
        description="pin the service to these CPUs (a core of its own keeps the control "
        "loop's latency tail short on a shared machine; [] = no pinning)",
    )

    def fixating(self) -> list[str]:
        return self.cameras or FIXATING.get(self.robot, [])
