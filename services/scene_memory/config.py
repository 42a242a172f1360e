"""Settings of the scene memory service (env AVS_SCENE_MEMORY_<FIELD> or --flag)."""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar, Literal

from pydantic import Field

from services.common.config import ServiceSettings


class SceneMemorySettings(ServiceSettings):
    """Fused scene model, support graph with occ(e), occupancy map, registered cloud."""

    SERVICE: ClassVar[str] = "scene_memory"

    data_dir: Path = Field(Path("avs-data/scene_memory"), description="journal and snapshots")
    fusion: Literal["pc", "sg", "pc+sg"] = Field("sg", description="support-graph combination")
    camera: str = Field("head_rgbd", description="camera whose depth frames fill the map")
    voxel: float = Field(0.01, gt=0, description="occupancy voxel size, m")
    bounds_min: list[float] = Field([-1.0, -2.5, -0.05], description="map's min corner x,y,z")
    bounds_max: list[float] = Field([4.0, 2.5, 2.2], description="map's max corner x,y,z")
    roi_min: list[float] | None = Field(None, description="default box of occupancy stats")
    roi_max: list[float] | None = None
    max_range: float = Field(3.0, gt=0, description="rays clear space up to this range, m")
    map_stride: int = Field(
        2, ge=1, description="every n-th pixel of a depth frame, each way, casts a ray into the map"
    )
    keyframe_move: float = Field(
        0.03, ge=0, description="a depth frame is integrated once the camera moved this far, m"
    )
    keyframe_turn: float = Field(3.0, ge=0, description="… or turned this much, degrees")
    max_pixels: int = Field(1280 * 960, gt=0, description="larger depth frames are dropped")
    slice_page_voxels: int = Field(
        4_000_000, ge=1, description="voxels per reply of memory/occupancy/slice (it pages)"
    )
    snapshot_every: int = Field(20, ge=1, description="updates between snapshots")
    max_replay_s: float = Field(
        0.5, gt=0, description="a snapshot once the journal since the last took this long"
    )
    snapshot_share: float = Field(
        0.1,
        gt=0,
        le=1,
        description="… but snapshots take at most this share of the time: a "
        "restart replays at most max(max_replay_s, the last snapshot's time × (1/share − 1))",
    )
    registration: bool = Field(
        False,
        description="register each integrated frame against the cloud so far (thesis A.5: "
        "point-to-plane ICP from the odometry pose) and publish memory/pose_correction",
    )
    registration_dof: Literal["planar", "full"] = Field(
        "planar",
        description="… solving for: 'planar', a wheeled platform's odometry drift (x, y and yaw "
        "about the world's vertical; the camera's height, roll and pitch are the kinematics' "
        "and are kept), or 'full', all six (a hand-held camera, a platform that is not level)",
    )
    odometry_noise: float = Field(
        0.0,
        ge=0,
        description="… the odometry's error as a share of the camera's motion (0.02: 2 %% of "
        "the distance and of the turn): each registration is then weighed against it and "
        "registration_noise in a Kalman filter, and refused where neither explains it "
        "(χ² 99.9 %%); 0: each registration is taken as it comes (thesis A.5)",
    )
    registration_noise: list[float] = Field(
        [0.02, 1.0],
        min_length=2,
        max_length=2,
        description="… a registration's error σ with odometry_noise: m,degrees",
    )
    registration_search: bool = Field(
        True,
        description="… where a frame is refused as too far from the map, register it again from "
        "seeds over the odometry's uncertainty (turns of ±3° and ±6°, shifts of ±8 cm) and take "
        "the answer only when no other fits as well elsewhere (else 'ambiguous')",
    )
    registration_search_window: list[float] = Field(
        [0.1, 4.0],
        min_length=2,
        max_length=2,
        description="… the odometry error the search is for, m,degrees: no hypothesis farther "
        "from the odometry's pose is taken (the sim's odometry: 1.5 %% of the distance, 1° a turn)",
    )
    registration_interval: float = Field(
        0.5,
        ge=0,
        description="… at most every this many seconds of capture time; a frame in between "
        "takes the last correction (odometry drifts 1.5 %% of the distance driven: 4 mm in "
        "0.5 s at 0.5 m/s) and its correction says 'not_due'; 0: every frame",
    )
