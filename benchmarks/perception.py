"""One 640×480 tabletop_clutter frame (start view, depth noise on) through three pipelines,
each scored with the same InlierIndex (thesis Eq. 3.11) against the ground truth:

- ours: the whole perception pipeline (cloud, segmentation, Algorithm 1, boxes, graphs,
  affordances);
- pyRANSAC-3D: our cloud and segments, each fitted by Algorithm 1 with pyransac3d's Plane,
  Cylinder and Sphere (best by inliers, remove, repeat) — the same work Algorithm 1 does;
- Open3D: a plain loop of ``segment_plane`` on the frame's cloud (planes only).

Last line: perception_ms=<ours> speedup_vs_pyransac3d=<x> inlier_index=<ours>
inlier_index_pyransac3d=<theirs>
Targets (issue 4): ≤ 150 ms median; ≥ 20× faster than pyRANSAC-3D at equal or better InlierIndex.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import open3d as o3d  # noqa: E402
import pyransac3d as pyrsc  # noqa: E402

from avs import evaluation  # noqa: E402
from avs.commands.perceive import look_target  # noqa: E402
from schemas import BoxModel, CylinderModel, Obb, PlaneModel, Primitive, SphereModel  # noqa: E402
from services.perception.cloud import organized_cloud  # noqa: E402
from services.perception.obb import axis_box, pca_box, plane_box  # noqa: E402
from services.perception.pipeline import Perception, observation  # noqa: E402
from services.perception.segmentation import segment  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World  # noqa: E402

TAU_MIN = 60
THRESH = 0.01


def primitive(pid: int, kind: str, points: np.ndarray, **model) -> Primitive:
    if kind == "plane":
        n = np.asarray(model["normal"], float)
        box = plane_box(points, n / np.linalg.norm(n))
        m = PlaneModel(normal=n / np.linalg.norm(n), d=model["d"] / np.linalg.norm(n))
    elif kind == "cylinder":
        a = np.asarray(model["axis"], float)
        a /= np.linalg.norm(a)
        box = axis_box(points, a, np.asarray(model["center"], float), model["radius"])
        m = CylinderModel(center=box.center, axis=a, radius=model["radius"], height=box.extent[2])
    elif kind == "sphere":
        box = pca_box(points)
        m = SphereModel(center=np.asarray(model["center"], float), radius=model["radius"])
    else:
        box = pca_box(points)
        m = BoxModel(center=box.center, rotation=box.rotation, extent=box.extent)
    return Primitive(
        id=pid,
        model=m,
        obb=Obb(center=box.center, rotation=box.rotation, extent=box.extent),
        inlier_count=len(points),
        inliers=points[:2000].astype(np.float32),
    )


def pyransac3d_pipeline(frame) -> tuple[list[Primitive], float]:
    """Our cloud and segments; Algorithm 1 with pyRANSAC-3D's fits."""
    t0 = time.perf_counter()
    K = frame.intrinsics
    cloud = organized_cloud(frame.depth, frame.rgb, K.fx, K.fy, K.cx, K.cy, frame.T_world_camera)
    labels, n = segment(cloud)
    P = cloud.points.reshape(-1, 3).astype(np.float64)
    prims: list[Primitive] = []
    for s in range(n):
        remaining = P[labels.ravel() == s]
        while len(remaining) >= TAU_MIN:
            fits = []
            eq, inl = pyrsc.Plane().fit(remaining, thresh=THRESH)
            if len(inl):
                fits.append(("plane", inl, {"normal": eq[:3], "d": eq[3]}))
            if len(remaining) >= 10:
                c, a, r, inl = pyrsc.Cylinder().fit(remaining, thresh=THRESH, maxIteration=1000)
                if len(inl) and 0 < r < 0.25:
                    fits.append(("cylinder", inl, {"center": c, "axis": a, "radius": r}))
                c, r, inl = pyrsc.Sphere().fit(remaining, thresh=THRESH)
                if len(inl) and 0 < r < 0.25:
                    fits.append(("sphere", inl, {"center": c, "radius": r}))
            if not fits:
                break
            kind, inl, model = max(fits, key=lambda f: len(f[1]))
            if len(inl) < TAU_MIN:
                break
            prims.append(primitive(len(prims), kind, remaining[inl], **model))
            keep = np.ones(len(remaining), bool)
            keep[inl] = False
            remaining = remaining[keep]
        print(f"\r  pyRANSAC-3D: segment {s + 1}/{n}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    return prims, (time.perf_counter() - t0) * 1e3


def open3d_pipeline(frame) -> tuple[list[Primitive], float]:
    """segment_plane until fewer than 2 % of the points are left (at most 20 planes)."""
    t0 = time.perf_counter()
    K = frame.intrinsics
    z = frame.depth
    v, u = np.nonzero((z > 0.35) & (z < 3.0))
    d = z[v, u].astype(np.float64)
    cam = np.column_stack([(u - K.cx) / K.fx * d, (v - K.cy) / K.fy * d, d])
    pts = cam @ frame.T_world_camera[:3, :3].T + frame.T_world_camera[:3, 3]
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    prims: list[Primitive] = []
    total = len(pts)
    while len(pcd.points) > 0.02 * total and len(prims) < 20:
        model, inl = pcd.segment_plane(THRESH, 3, 1000)
        if len(inl) < TAU_MIN:
            break
        inliers = np.asarray(pcd.points)[inl]
        prims.append(primitive(len(prims), "plane", inliers, normal=model[:3], d=model[3]))
        pcd = pcd.select_by_index(inl, invert=True)
    return prims, (time.perf_counter() - t0) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15, help="runs of our pipeline")
    args = parser.parse_args()

    world = World("tabletop_clutter", ARMAR6)
    world.look_at(look_target(world))
    renderer = CameraRenderer(world.model, 640, 480)
    frame, gt = capture.view(world, renderer, "head_rgbd", np.random.default_rng(0))
    renderer.close()
    segments = evaluation.labelled_points(gt, frame.depth, frame.intrinsics, frame.T_world_camera)

    perception = Perception()
    perception.warm_up()
    times = []
    for i in range(args.repeats):
        t0 = time.perf_counter()
        result = perception.perceive(frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera)
        times.append((time.perf_counter() - t0) * 1e3)
        print(f"\r  ours: run {i + 1}/{args.repeats}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    ours_ms = float(np.median(times))
    obs = observation(result, frame, 0, "bench", 3.0, perception.config.stride)
    ours_ii = evaluation.score_primitives(segments, obs.primitives).inlier_index
    stages = {k: round(float(v), 1) for k, v in result.timings_ms.items()}

    o3d_times, o3d_prims = [], []
    for _ in range(3):
        o3d_prims, ms = open3d_pipeline(frame)
        o3d_times.append(ms)
    o3d_ii = evaluation.score_primitives(segments, o3d_prims).inlier_index
    pyr_prims, pyr_ms = pyransac3d_pipeline(frame)
    pyr_ii = evaluation.score_primitives(segments, pyr_prims).inlier_index

    print(
        f"ours          median {ours_ms:8.1f} ms  InlierIndex {ours_ii:.3f}  "
        f"{len(obs.primitives)} primitives  stages {stages}"
    )
    print(
        f"pyRANSAC-3D          {pyr_ms:8.1f} ms  InlierIndex {pyr_ii:.3f}  "
        f"{len(pyr_prims)} primitives"
    )
    print(
        f"Open3D planes median {np.median(o3d_times):8.1f} ms  InlierIndex {o3d_ii:.3f}  "
        f"{len(o3d_prims)} planes"
    )
    print(
        f"perception_ms={ours_ms:.1f} speedup_vs_pyransac3d={pyr_ms / ours_ms:.1f} "
        f"inlier_index={ours_ii:.3f} inlier_index_pyransac3d={pyr_ii:.3f}"
    )


if __name__ == "__main__":
    main()
