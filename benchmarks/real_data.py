"""Real RGB-D recordings through the real perception and scene memory (issue 42, item 4).

For every recording in ``--data`` (default ``AVS_REAL_DATA``, else ``../shared/data/real``
beside the checkout: see its README for what each holds and where it comes from), on a
loopback Zenoh router in this process (multicast off) with perception and the scene memory as
processes, each with its defaults except a fresh data directory and a queue that holds the
whole recording (so that every frame is perceived, however slow):

- **model** run: ``avs replay-dataset DIR --up auto`` as a user plays it (the reference poses,
  registration off). Per recording: frames played, observations the memory received (on
  ``perception/observation``), perception's own time per frame (the observations'
  ``timings_ms["total"]``, median), the fused primitives by kind (the memory's ``memory/scene``
  at the end), the heights of the large level planes in it (normal within 10° of z, longest
  side ≥ 0.3 m: the floor, table tops), the share of the fused primitives marked unstable
  (``SceneModel.unstable_ids``: no support found, and a view saw nothing under them) and the
  share whose support is unresolved (``unresolved_ids``: none found, none seen under them);
- **drift** run, where the recording has poses, once per ``--dof`` (the registration's
  unknowns, ``AVS_SCENE_MEMORY_REGISTRATION_DOF``: ``planar``, a ground platform's x, y and
  yaw, or ``full``) and once more per ``--weighed-dof`` (default planar) with each
  registration weighed against an odometry that errs by ``--odometry-noise`` (2 %) of the
  motion (``AVS_SCENE_MEMORY_ODOMETRY_NOISE``, ``correction_filter.py``; by default the memory
  takes each as it comes): the same with ``--drift 0.5,0.02`` (the k-th frame's pose moved
  k·0.5 mm along +x and turned k·0.02° of yaw about the first camera's vertical, moving or
  not: ``services/adapters/dataset/drift.py``) and the memory's view registration on
  (``AVS_SCENE_MEMORY_REGISTRATION=true``, its other settings at their defaults: every 0.5 s
  of the recording's stamps; but every frame integrated, no keyframe policy: it decides on the
  drifted pose, and 0.5 mm can take a frame across its 3 cm, so the drifted and the still run
  would integrate different frames). The camera pose the memory holds for a frame is its
  ``memory/pose_correction`` (``T_world_odom``, the last accepted correction) times the pose
  the frame carried; its error is taken against the reference pose (turned by the same
  ``T_up``), at every frame played and at the last one, next to the error without
  registration (the full drift);
- **still** run, per ``--dof``: registration on, no drift: what registration makes of the
  reference poses themselves. The drift run's held poses are compared with this run's, frame
  by frame: ``drift_residual`` is how much of the drift registration failed to undo,
  whatever the reference's own disagreement with the depth (which ``pose_error`` includes:
  on a Kinect v1 with its depth distortion that alone is ~1 cm). It is a fair comparison
  only where both runs integrated and registered the same frames: ``same_frames``.

Recordings are played at ``--rate`` of their own timing (default 0.25: the scene memory takes
every depth frame it can and drops the ones that came while it was busy, as it does live;
integrating every frame at 0.5 it dropped 1-2 of redkitchen-a's 6 a second, different ones in
each run, and the registrations fell on other frames; at 0.25 none: ``same_frames``). Progress on
stderr; ``OUT/real_data.json`` holds every figure and per frame pose error,
``OUT/real_data_<recording>.png`` the pose error per frame with and without registration.
One line per recording, and one per recording with poses and ``--dof``:

recording=<name> frames=<n> observations=<n> perception_ms=<median> primitives=<n>
plane=<n> cylinder=<n> sphere=<n> box=<n> level_planes_m=<h>x<n>,… unstable_share=<x>
unresolved_share=<x>

recording=<name> dof=<planar|full> odometry_noise=<a: 0 taken as they come> pose_error_mm=<x>
pose_error_deg=<x> pose_error_mm_median=<x> pose_error_mm_max=<x> drift_error_mm=<x>
drift_error_deg=<x> drift_residual_mm=<x> drift_residual_deg=<x> drift_residual_mm_max=<x>
still_pose_error_mm=<x> mapped=<n> registered=<n> refused=<n> still_mapped=<n>
still_registered=<n> same_frames=<yes|no> reference_offset_mm_median=<x>
reference_offset_mm_max=<x> revisits=<n> revisit_mm_reference=<x> revisit_mm_registered=<x>
revisit_mm_drift=<x>

``level_planes_m``: the level planes' heights in runs 3 cm wide, each as its median and how many
fused planes it holds (a table top fused as one plane is ``0.72x1``). ``mapped``: the frames the
memory integrated (all of them unless it dropped some), ``registered``: of them, those
registration placed, ``refused``: those it refused (the others were not due).
``reference_offset_mm_*``: in this process, every 3rd frame at its *reference* pose registered
against a map of the frames before it at theirs, how far registration moves it (median, max):
about 0 where depth and reference agree; the target needs it well under 10.
``pose_error``, ``drift_residual``: at the last frame (``pose_error_mm_median``, ``_max``,
``drift_residual_mm_max``: over the frames); ``still_pose_error_mm``: the still run's at the
last frame.
``same_frames``: the two runs integrated the same frames, tried registration on the same and
accepted the same ones (``mapped`` = ``frames``: none dropped).
``revisit_mm_*``: whether a set of poses agrees with the depth, judged by the depth alone
(``revisit_errors``): for ``revisits`` pairs of frames at least 20 apart that see the same
place, how far the relative pose the two depth frames give by themselves (Open3D's ICP, which
converges to the same pose from either set's start, within ~1 mm) is from the set's, median:
the ``reference`` poses, the poses the memory held with the drift (``registered``) and the
drifted poses alone (``drift``). On redkitchen-a the reference scores ~14 mm (a Kinect v1's
pairwise noise) and registration's poses taken as they come ~50 mm: the registration's walk
(each registration a frame-to-map fit, off by up to ~5 cm where the camera turns fast,
``reference_offset_mm_max``, and the next frame fitted to it), not the reference's
disagreement with the depth. Weighed against the odometry's error (``--odometry-noise``) the
walk is averaged out (in process, 2026-12-06, planar: median over the frames 42 → 10 mm).

Target (issue 42): with the drift, pose_error_mm ≤ 10 on ``redkitchen-a``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from avs.router import open_router  # noqa: E402
from benchmarks._loopback import client_config, free_endpoint, stop  # noqa: E402
from schemas import Keys, PoseCorrection, SceneModel, SceneObservation, decode  # noqa: E402
from services.adapters.dataset.drift import Drift  # noqa: E402
from services.adapters.dataset.formats import DatasetError, read  # noqa: E402
from services.adapters.dataset.frames import DatasetFrames  # noqa: E402
from services.common.poses import pose_difference  # noqa: E402
from services.scene_memory.config import SceneMemorySettings  # noqa: E402
from services.scene_memory.memory import MemoryConfig  # noqa: E402
from services.scene_memory.registration import (  # noqa: E402
    RegistrationConfig,
    RegistrationMap,
    camera_points,
    register,
)

CAMERA = "head_rgbd"
#: the registration runs' odometry error model (``--odometry-noise``): 2 % of the motion, what
#: a user states for a wheeled platform's odometry (``correction_filter.OdometryNoise``)
ODOMETRY_NOISE = 0.02
#: the issue's drift: 0.5 mm and 0.02° of yaw added each frame
DRIFT = Drift(0.5, 0.02)
#: a level plane: normal within this of z (°), longest side at least this (m)
LEVEL_DEG, LEVEL_SIDE = 10.0, 0.3
#: s without a new observation, correction or model after the replay before a run is over
QUIET_S = 8.0


def default_data() -> Path:
    return Path(os.environ.get("AVS_REAL_DATA", ROOT.parent / "shared" / "data" / "real"))


def recordings(data: Path) -> list[Path]:
    """The folders of ``data`` that ``avs replay-dataset`` can read, by name."""
    out = []
    for d in sorted(p for p in data.iterdir() if p.is_dir()):
        try:
            read(d)
        except DatasetError:
            continue
        out.append(d)
    return out


@dataclass
class Received:
    """What the run's client heard, from Zenoh's callbacks."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    observations: list[tuple[int, float]] = field(default_factory=list)  # (frame_seq, ms)
    corrections: list[PoseCorrection] = field(default_factory=list)
    models: int = 0
    last: float = field(default_factory=time.monotonic)  # the last arrival, monotonic

    def note(self) -> None:
        self.last = time.monotonic()


def _services(
    endpoint: str,
    data_dir: Path,
    registration: bool,
    frames: int,
    log,
    dof: str = "planar",
    odometry_noise: float = 0.0,
) -> list:
    env = dict(
        os.environ, AVS_MODE="client", AVS_CONNECT=endpoint, AVS_MULTICAST="false",
        AVS_LOG_LEVEL="WARNING", PYTHONPATH=str(ROOT),
        AVS_PERCEPTION_QUEUE=str(max(frames, 2)),
        AVS_SCENE_MEMORY_DATA_DIR=str(data_dir),
        AVS_SCENE_MEMORY_REGISTRATION="true" if registration else "false",
        AVS_SCENE_MEMORY_REGISTRATION_DOF=dof,
        AVS_SCENE_MEMORY_ODOMETRY_NOISE=str(odometry_noise),
    )  # fmt: skip
    if registration:  # every frame integrated: the drifted and the still run, the same frames
        env |= {"AVS_SCENE_MEMORY_KEYFRAME_MOVE": "0", "AVS_SCENE_MEMORY_KEYFRAME_TURN": "0"}
    return [
        subprocess.Popen(
            [sys.executable, "-m", f"services.{name}", "--instance", f"real-{name}"],
            env=env,
            cwd=ROOT,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        for name in ("perception", "scene_memory")
    ]


def _wait_alive(session: zenoh.Session, keys: Keys, procs: list, timeout: float = 180) -> None:
    wanted = {keys.alive(n, f"real-{n}") for n in ("perception", "scene_memory")}
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        live = {str(r.ok.key_expr) for r in session.liveliness().get(keys.alive()) if r.ok}
        if wanted <= live:
            return
        if any(p.poll() is not None for p in procs):
            raise RuntimeError("a service exited before it was up (see its log in --out)")
        time.sleep(0.3)
    raise RuntimeError(f"services not up within {timeout:.0f} s")


def level_planes(model: SceneModel) -> list[float]:
    """Heights (m) of the model's large level planes, lowest first."""
    cos = math.cos(math.radians(LEVEL_DEG))
    out = []
    for p in model.primitives:
        if p.kind != "plane" or abs(float(p.model.normal[2])) < cos:
            continue
        if float(np.max(p.obb.extent)) < LEVEL_SIDE:
            continue
        out.append(round(float(p.obb.center[2]), 3))
    return sorted(out)


def grouped(heights: list[float], within: float = 0.03) -> list[tuple[float, int]]:
    """Sorted heights in runs no wider than ``within`` (m): (the run's median, its count)."""
    runs: list[list[float]] = []
    for h in sorted(heights):
        if runs and h - runs[-1][0] <= within:
            runs[-1].append(h)
        else:
            runs.append([h])
    return [(round(float(np.median(r)), 3), len(r)) for r in runs]


def model_figures(model: SceneModel) -> dict:
    kinds = Counter(p.kind for p in model.primitives)
    n = len(model.primitives)
    return {
        "primitives": n,
        **{k: kinds.get(k, 0) for k in ("plane", "cylinder", "sphere", "box")},
        "level_planes_m": level_planes(model),
        "unstable_share": round(len(model.unstable_ids) / n, 3) if n else 0.0,
        "unresolved_share": round(len(model.unresolved_ids) / n, 3) if n else 0.0,
    }


def pose_errors(frames: DatasetFrames, corrections: list[PoseCorrection]) -> dict:
    """Per played frame, the error of the pose the memory holds (its last correction before
    or at the frame, times the pose the frame carried) and of the pose alone (the drift)."""
    chosen = frames.indices()
    by_seq = sorted(corrections, key=lambda c: c.frame_seq)
    T_corr, j, rows, held = np.eye(4), 0, [], []
    for seq, i in enumerate(chosen):
        while j < len(by_seq) and by_seq[j].frame_seq <= seq:
            T_corr = by_seq[j].T_world_odom
            j += 1
        truth, carried = frames.pose(i), frames.published_pose(i, seq)
        held.append(T_corr @ carried)
        e_reg = pose_difference(truth, held[-1])
        e_drift = pose_difference(truth, carried)
        rows.append((seq, e_reg[0] * 1e3, e_reg[1], e_drift[0] * 1e3, e_drift[1]))
    last = rows[-1]
    return {
        "pose_error_mm": round(last[1], 1), "pose_error_deg": round(last[2], 2),
        "pose_error_mm_median": round(float(np.median([r[1] for r in rows])), 1),
        "pose_error_mm_max": round(max(r[1] for r in rows), 1),
        "drift_error_mm": round(last[3], 1), "drift_error_deg": round(last[4], 2),
        "mapped": len(corrections),
        "registered": sum(c.accepted for c in corrections[1:]),
        "refused": sum(not c.accepted and c.reason != "not_due" for c in corrections),
        "reasons": dict(Counter(c.reason for c in corrections if not c.accepted)),
        "per_frame": [[round(v, 2) for v in r] for r in rows],
        "held": [np.round(T, 7).tolist() for T in held],
        "mapped_seqs": sorted(c.frame_seq for c in corrections),
        "registered_seqs": sorted(c.frame_seq for c in corrections if c.accepted),
        "tried_seqs": sorted(c.frame_seq for c in corrections if c.reason != "not_due"),
    }  # fmt: skip


def drift_residual(drifted: dict, still: dict) -> dict:
    """How far the poses the memory holds with the drift are, frame by frame, from those it
    holds for the same frames without (registration on in both; ``pose_errors``' figures):
    the drift registration did not undo, apart from the reference's own disagreement with the
    depth, which both share. At the last frame, and the largest (mm)."""
    pairs = [
        (np.array(a), np.array(b)) for a, b in zip(drifted["held"], still["held"], strict=True)
    ]
    d = [pose_difference(b, a) for a, b in pairs]
    same = all(drifted[k] == still[k] for k in ("mapped_seqs", "registered_seqs", "tried_seqs"))
    return {
        "drift_residual_mm": round(d[-1][0] * 1e3, 1),
        "drift_residual_deg": round(d[-1][1], 2),
        "drift_residual_mm_max": round(max(m for m, _ in d) * 1e3, 1),
        "drift_residual_per_frame_mm": [round(m * 1e3, 2) for m, _ in d],
        "still_pose_error_mm": still["pose_error_mm"],
        "still_mapped": still["mapped"],
        "still_registered": still["registered"],
        "same_frames": "yes" if same else "no",
    }


def reference_offsets(frames: DatasetFrames, every: int = 3, dof: str = "planar") -> dict:
    """What the registration makes of the reference poses themselves, in this process: every
    ``every``-th frame, at its reference pose, registered (the memory's settings) against a map
    of the frames before it at theirs; how far registration moves it (mm). Where the depth and
    the reference poses agree this is about 0, and it bounds from below what registration can
    do against drift measured from the reference."""
    c, m = RegistrationConfig(dof=dof), MemoryConfig()
    depth_max = SceneMemorySettings.model_fields["max_range"].default
    target, moved = RegistrationMap(c), []
    for seq, i in enumerate(frames.indices()):
        f = frames.frame(i, seq)
        T, K = frames.pose(i), f.intrinsics
        points = camera_points(f.depth, K, m.depth_min, depth_max)
        if seq and seq % every == 0:
            r = register(points, T, target, c)
            if r.accepted:
                moved.append(pose_difference(T, r.T_world_camera)[0] * 1e3)
        target.add(points @ T[:3, :3].T + T[:3, 3])
    return {
        "reference_offset_mm_median": round(float(np.median(moved)), 1) if moved else math.nan,
        "reference_offset_mm_max": round(float(np.max(moved)), 1) if moved else math.nan,
        "reference_offsets_mm": [round(v, 1) for v in moved],
    }


def revisits(
    clouds: list[np.ndarray], poses: list[np.ndarray], gap: int, overlap: float, at_most: int
) -> list[tuple[int, int]]:
    """Frame pairs at least ``gap`` apart whose views overlap at ``poses``: at least
    ``overlap`` of the first's points within 2 cm of the second's; every 2nd frame, at most
    ``at_most`` pairs spread evenly over them."""
    from scipy.spatial import cKDTree

    trees = [cKDTree(c) for c in clouds]
    out = []
    for i in range(0, len(clouds), 2):
        for j in range(i + gap, len(clouds), 2):
            rel = np.linalg.inv(poses[j]) @ poses[i]
            d, _ = trees[j].query(clouds[i] @ rel[:3, :3].T + rel[:3, 3], distance_upper_bound=0.02)
            if np.isfinite(d).mean() >= overlap:
                out.append((i, j))
    step = max(1, -(-len(out) // at_most))
    return out[::step]


#: pairwise ICP on depth alone, coarse to fine: its reach and Tukey's k, m
ICP_PASSES = ((0.08, 0.04), (0.04, 0.02), (0.02, 0.01))


def depth_clouds(frames: DatasetFrames) -> tuple[list, list]:
    """Per played frame, its depth in its camera's frame (``camera_points``, the scene
    memory's depth range) as Open3D clouds: the source side at 2 cm, the target side at
    1.5 cm with normals."""
    import open3d as o3d

    m, depth_max = MemoryConfig(), SceneMemorySettings.model_fields["max_range"].default
    sources, targets = [], []
    for seq, i in enumerate(frames.indices()):
        f = frames.frame(i, seq)
        pts = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
            camera_points(f.depth, f.intrinsics, m.depth_min, depth_max)))  # fmt: skip
        sources.append(pts.voxel_down_sample(0.02))
        target = pts.voxel_down_sample(0.015)
        target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.04, max_nn=30))
        targets.append(target)
    return sources, targets


def pairwise_icp(source, target, T0: np.ndarray):
    """Open3D's point-to-plane ICP with Tukey's loss, coarse to fine (``ICP_PASSES``) from
    ``T0`` (source → target): its last result (transformation, fitness)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    result, T = None, T0
    for reach, kernel in ICP_PASSES:
        result = reg.registration_icp(
            source, target, reach, T,
            reg.TransformationEstimationPointToPlane(reg.TukeyLoss(k=kernel)),
            reg.ICPConvergenceCriteria(max_iteration=50),
        )  # fmt: skip
        T = result.transformation
    return result


def revisit_errors(
    frames: DatasetFrames, sets: dict[str, list[np.ndarray]], gap: int = 20,
    overlap: float = 0.6, at_most: int = 40, clouds: tuple[list, list] | None = None,
) -> dict:  # fmt: skip
    """How well each set of camera poses (``sets``, the played frames' poses, by name; one
    must be ``reference``) agrees with the depth where the camera came back to a place it saw
    ``gap`` frames or more before: for such pairs of frames (their views overlapping at the
    reference poses, ``revisits``), the relative pose the two depth frames give by themselves
    (``pairwise_icp`` of the one on the other from the set's relative pose: no code of the
    memory's registration) against the set's (mm, the first camera's position; median over
    the pairs). The reference only chooses the pairs: a set whose frames are placed
    consistently scores the depth's own pairwise noise (~1 cm on a Kinect v1), one that
    walked scores the walk between the two visits. ``clouds``: ``depth_clouds(frames)``
    when already at hand."""
    sources, targets = clouds or depth_clouds(frames)
    points = [np.asarray(s.points) for s in sources]
    pairs = revisits(points, sets["reference"], gap, overlap, at_most)
    out: dict = {"revisits": len(pairs)}
    for name, poses in sets.items():
        errors = []
        for i, j in pairs:
            rel = np.linalg.inv(poses[j]) @ poses[i]
            T = pairwise_icp(sources[i], targets[j], rel).transformation
            errors.append(float(np.linalg.norm(T[:3, 3] - rel[:3, 3])) * 1e3)
        out[f"revisit_mm_{name}"] = round(float(np.median(errors)), 1) if errors else math.nan
        out[f"revisit_mm_{name}_all"] = [round(e, 1) for e in errors]
    out["revisit_pairs"] = pairs
    return out


def held_revisits(root: Path, drifted: dict, limit: int = 0) -> dict:
    """``revisit_errors`` of the reference poses, the poses the memory held in the drift run
    (``registered``) and the drifted poses alone (``drift``)."""
    frames = DatasetFrames(read(root), limit=limit, drift=DRIFT, colour=False)
    frames.T_up = np.array(drifted["T_up"])
    chosen = frames.indices()
    return revisit_errors(frames, {
        "reference": [frames.pose(i) for i in chosen],
        "registered": [np.array(T) for T in drifted["held"]],
        "drift": [frames.published_pose(i, seq) for seq, i in enumerate(chosen)],
    })  # fmt: skip


def run_recording(
    root: Path,
    out: Path,
    *,
    drift: Drift | None = None,
    registration: bool = False,
    rate: float = 0.25,
    every: int = 1,
    limit: int = 0,
    tag: str = "model",
    dof: str = "planar",
    offsets: bool = True,
    odometry_noise: float = 0.0,
) -> dict:
    """Play ``root`` into a fresh perception and scene memory; what they made of it. With
    registration on a recording with poses, the poses the memory held per frame (``drift``
    None: none given), and with ``offsets`` the reference offsets (``reference_offsets``)."""
    keys = Keys()
    frames_total = len(DatasetFrames(read(root), every=every, limit=limit).indices())
    endpoint = free_endpoint()
    router = open_router([endpoint])
    got = Received()
    up_file = out / f"up_{root.name}_{tag}.json"
    log = open(out / f"services_{root.name}_{tag}.log", "w")  # noqa: SIM115
    with tempfile.TemporaryDirectory(prefix="avs-real-") as data_dir:
        procs = _services(endpoint, Path(data_dir), registration, frames_total, log, dof,
                          odometry_noise)  # fmt: skip
        try:
            with zenoh.open(client_config(endpoint)) as session:

                def on_observation(sample: zenoh.Sample) -> None:
                    o = decode(sample.payload.to_bytes(), SceneObservation)
                    with got.lock:
                        got.observations.append((o.frame_seq, o.timings_ms.get("total", 0.0)))
                        got.note()

                def on_correction(sample: zenoh.Sample) -> None:
                    c = decode(sample.payload.to_bytes(), PoseCorrection)
                    with got.lock:
                        got.corrections.append(c)
                        got.note()

                def on_model(_sample: zenoh.Sample) -> None:
                    with got.lock:
                        got.models += 1
                        got.note()

                subs = [
                    session.declare_subscriber(keys.observation(), on_observation),
                    session.declare_subscriber(keys.pose_correction(), on_correction),
                    session.declare_subscriber(keys.scene(), on_model),
                ]
                _wait_alive(session, keys, procs)
                command = [
                    sys.executable, "-m", "avs.cli", "replay-dataset", str(root), "--up", "auto",
                    "--up-file", str(up_file), "--rate", str(rate), "--every", str(every),
                    "--limit", str(limit), "--camera", CAMERA, "--connect", endpoint,
                ]  # fmt: skip
                if drift is not None:
                    command += ["--drift", f"{drift.mm},{drift.deg}"]
                env = dict(os.environ, AVS_MODE="client", AVS_MULTICAST="false",
                           PYTHONPATH=str(ROOT))  # fmt: skip
                subprocess.run(command, cwd=ROOT, env=env, check=True, timeout=1800)
                # the services finish what they were sent: nothing new for QUIET_S
                while time.monotonic() - got.last < QUIET_S:
                    with got.lock:
                        if len(got.observations) >= frames_total and got.models:
                            break
                    time.sleep(0.2)
                time.sleep(1.0)  # the model of the last observations, the last correction
                replies = list(session.get(keys.scene(), timeout=30.0))
                model = decode(replies[0].ok.payload.to_bytes(), SceneModel)
                for s in subs:
                    s.undeclare()
        finally:
            stop(procs)
            router.close()
            log.close()
    with got.lock:
        observations, corrections = list(got.observations), list(got.corrections)
    figures = {
        "frames": frames_total,
        "observations": len(observations),
        "perception_ms": round(float(np.median([ms for _, ms in observations])), 1)
        if observations
        else math.nan,
        **model_figures(model),
    }
    if registration and read(root).poses is not None:
        frames = DatasetFrames(read(root), every=every, limit=limit, drift=drift)
        frames.T_up = np.array(json.loads(up_file.read_text())["T_up"])
        figures |= pose_errors(frames, corrections) | {
            "T_up": frames.T_up.tolist(), "dof": dof, "odometry_noise": odometry_noise
        }  # fmt: skip
        if offsets:
            figures |= reference_offsets(frames, dof=dof)
    return figures


def line(name: str, model: dict) -> str:
    keys = ("frames", "observations", "perception_ms", "primitives", "plane", "cylinder",
            "sphere", "box")  # fmt: skip
    parts = [f"recording={name}", *(f"{k}={model[k]}" for k in keys)]
    levels = grouped(model["level_planes_m"])
    parts.append("level_planes_m=" + (",".join(f"{h:.2f}x{n}" for h, n in levels) or "-"))
    parts.append(f"unstable_share={model['unstable_share']}")
    parts.append(f"unresolved_share={model['unresolved_share']}")
    return " ".join(parts)


def drift_line(name: str, drift: dict) -> str:
    keys = ("dof", "odometry_noise", "pose_error_mm", "pose_error_deg", "pose_error_mm_median",
            "pose_error_mm_max", "drift_error_mm", "drift_error_deg",
            "drift_residual_mm", "drift_residual_deg", "drift_residual_mm_max",
            "still_pose_error_mm", "mapped", "registered", "refused", "still_mapped",
            "still_registered", "same_frames", "reference_offset_mm_median",
            "reference_offset_mm_max", "revisits", "revisit_mm_reference",
            "revisit_mm_registered", "revisit_mm_drift")  # fmt: skip
    return " ".join([f"recording={name}", *(f"{k}={drift[k]}" for k in keys)])


def error_plot(title: str, ylabel: str, curves: list[tuple], path: Path) -> None:
    """Camera position error per frame against the 10 mm target: ``curves`` of (x, y, the
    plot's keywords), one per line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.2))
    for x, y, style in curves:
        ax.plot(x, y, **style)
    ax.axhline(10, color="grey", lw=0.8, ls="--", label="target 10 mm")
    ax.set_xlabel("frame")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot(name: str, drifts: dict[str, dict], path: Path) -> None:
    curves = []
    for i, (dof, drift) in enumerate(drifts.items()):
        rows = np.array(drift["per_frame"])
        x = rows[:, 0]
        if i == 0:
            curves.append(
                (x, rows[:, 3], {"color": "k", "label": "without registration (the drift)"})
            )
        curves.append((x, rows[:, 1], {"label": f"{dof}: against the reference"}))
        residual = drift["drift_residual_per_frame_mm"]
        curves.append(
            (x, residual, {"ls": ":", "label": f"{dof}: against registration without drift"})
        )
    title = f"{name}: drift {DRIFT.mm} mm, {DRIFT.deg}° a frame"
    error_plot(title, "camera position error, mm", curves, path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=default_data(),
                        help="a folder of recordings (default AVS_REAL_DATA, else "
                        "../shared/data/real)")  # fmt: skip
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "real_data")
    parser.add_argument("--rate", type=float, default=0.25, help="of the recordings' timing")
    parser.add_argument("--limit", type=int, default=0, help="frames per recording (0: all)")
    parser.add_argument("--only", nargs="*", default=None, help="these recordings (names)")
    parser.add_argument(
        "--dof",
        nargs="+",
        choices=("planar", "full"),
        default=["planar", "full"],
        help="the registration's unknowns, a drift and a still run each",
    )
    parser.add_argument(
        "--weighed-dof",
        nargs="*",
        choices=("planar", "full"),
        default=["planar"],
        help="these unknowns again, each registration "
        "weighed against the odometry's error (--odometry-noise)",
    )
    parser.add_argument("--odometry-noise", type=float, default=ODOMETRY_NOISE,
                        help="the odometry's error as a share of the motion, for the weighed "
                        "runs (AVS_SCENE_MEMORY_ODOMETRY_NOISE)")  # fmt: skip
    args = parser.parse_args()
    if not args.data.is_dir():
        raise SystemExit(f"real_data: no recordings at {args.data} (see --data)")
    args.out.mkdir(parents=True, exist_ok=True)
    results, lines = {}, []
    for root in recordings(args.data):
        if args.only and root.name not in args.only:
            continue
        print(f"real_data: {root.name}: model run", file=sys.stderr, flush=True)
        model = run_recording(root, args.out, rate=args.rate, limit=args.limit)
        lines.append(line(root.name, model))
        print(lines[-1], flush=True)
        drifts: dict[str, dict] = {}
        if read(root).poses is not None:
            variants = [(dof, 0.0) for dof in args.dof]
            variants += [(dof, args.odometry_noise) for dof in args.weighed_dof]
            for dof, noise in variants:
                key = f"{dof}, weighed" if noise else dof
                runs = {}
                for tag, drift in (("still", None), ("drift", DRIFT)):
                    print(f"real_data: {root.name}: {tag} run (registration on, {key})",
                          file=sys.stderr, flush=True)  # fmt: skip
                    runs[tag] = run_recording(root, args.out, drift=drift, registration=True,
                                              rate=args.rate, limit=args.limit,
                                              tag=f"{tag}_{dof}{'_weighed' if noise else ''}",
                                              dof=dof, offsets=tag == "drift",
                                              odometry_noise=noise)  # fmt: skip
                if not np.allclose(runs["still"]["T_up"], runs["drift"]["T_up"], atol=1e-9):
                    print(f"real_data: {root.name}: the runs found different T_up",
                          file=sys.stderr)  # fmt: skip
                drifts[key] = runs["drift"] | drift_residual(runs["drift"], runs["still"])
                print(f"real_data: {root.name}: revisits ({key})", file=sys.stderr, flush=True)
                drifts[key] |= held_revisits(root, runs["drift"], args.limit)
                lines.append(drift_line(root.name, drifts[key]))
                print(lines[-1], flush=True)
            plot(root.name, drifts, args.out / f"real_data_{root.name}.png")
        results[root.name] = {"model": model, "drift": drifts}
    record = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "data": str(args.data),
              "rate": args.rate, "drift": [DRIFT.mm, DRIFT.deg], "recordings": results}  # fmt: skip
    (args.out / "real_data.json").write_text(json.dumps(record, indent=1))
    print(f"real_data: wrote {args.out / 'real_data.json'}", file=sys.stderr)


if __name__ == "__main__":
    main()
