"""Scoring perception against ground truth: thesis Eq. 3.8-3.12 and 4.14-4.16.

Inputs are wire messages only (GroundTruth, Primitive lists, support edges by primitive id)
plus the labelled ground-truth points, so the same functions score one frame, a fused scene
model, or a whole episode.

- ``Inlier(G_i, ψ) = |G_i ∩ OBB(ψ)| / |G_i|`` (Eq. 3.8), ψ(G_i) = argmax (Eq. 3.10),
  InlierIndex = mean over ground-truth segments (Eq. 3.11);
- OverlappingIndex (Eq. 3.12): the Jaccard index of G_i and the points ψ explains (within
  ``delta`` of its surface, inside its OBB), best over ψ, averaged;
- support graph precision / recall / F1 (Eq. 4.14-4.16) on the edges, after mapping
  primitives to bodies (each to the body more than half of its explained points belong to).
  Every perceived edge counts: one with an end that maps to no body (wherever its other end
  is), or with both ends on one body, is a false positive; edges between the same two bodies
  count once; edges between two bodies one of which is outside the region of interest are not
  judged;
- how the primitives map: ``vertex_precision`` (share of primitives that map to a body),
  ``segments_per_body`` (over-segmentation) and ``bodies_merged`` (primitives with at least
  ``MERGED_SHARE`` of their explained points on each of two or more bodies).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from schemas import CameraIntrinsics, GroundTruth, Primitive

#: points this close to a primitive's surface are explained by it (m)
DELTA = 0.015
#: margin of the OBB containment test of Eq. 3.8 (m): depth noise puts surface points a few
#: millimetres outside a face's box
OBB_MARGIN = 0.01
#: a primitive with at least this share of its explained points on each of two bodies merges them
MERGED_SHARE = 0.2


def labelled_points(
    gt: GroundTruth,
    depth: np.ndarray,
    intrinsics: CameraIntrinsics,
    T_world_camera: np.ndarray,
    *,
    depth_min: float = 0.35,
    depth_max: float = 3.0,
    stride: int = 2,
) -> dict[str, np.ndarray]:
    """World points of each ground-truth body seen in the frame (segmentation from ``gt``)."""
    if gt.segmentation is None:
        raise ValueError("the ground truth carries no segmentation")
    z = np.asarray(depth, np.float64)[::stride, ::stride]
    seg = gt.segmentation[::stride, ::stride]
    h, w = z.shape
    u = np.arange(0, w * stride, stride)[None, :]
    v = np.arange(0, h * stride, stride)[:, None]
    ok = np.isfinite(z) & (z >= depth_min) & (z <= depth_max) & (seg >= 0)
    cam = np.stack(
        [(u - intrinsics.cx) / intrinsics.fx * z, (v - intrinsics.cy) / intrinsics.fy * z, z], -1
    )
    world = cam[ok] @ T_world_camera[:3, :3].T + T_world_camera[:3, 3]
    label = seg[ok]
    out = {}
    for i, name in enumerate(gt.labels):
        if name != "robot" and np.any(label == i):
            out[name] = world[label == i]
    return out


def merge_points(sets: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Labelled points of several views together."""
    out: dict[str, list[np.ndarray]] = {}
    for s in sets:
        for k, v in s.items():
            out.setdefault(k, []).append(v)
    return {k: np.concatenate(v) for k, v in out.items()}


def obb_excess(p: Primitive, points: np.ndarray) -> np.ndarray:
    """How far each point lies outside OBB(ψ), along the axis it is furthest out on (m; ≤ 0
    inside): it is in the box grown by a margin m where this is ≤ m."""
    local = (points - p.obb.center) @ p.obb.rotation
    return (np.abs(local) - p.obb.extent / 2).max(axis=1)


def _x_reach(p: Primitive, margin: float) -> tuple[float, float]:
    """The world x interval that holds OBB(ψ) grown by ``margin`` on each side (with 1 mm to
    spare for a rotation a little off orthonormal): no point outside it is within the margin."""
    half = np.abs(np.asarray(p.obb.rotation)[0]) @ (np.asarray(p.obb.extent) / 2 + margin)
    return p.obb.center[0] - half - 1e-3, p.obb.center[0] + half + 1e-3


@dataclass
class Scores:
    inlier_index: float
    overlapping_index: float
    match: dict[str, int]  # ground-truth body → ψ(G_i) (Eq. 3.10)
    bodies: dict[int, str]  # primitive id → body it maps to
    vertex_precision: float = 0.0  # primitives that map to a body / all primitives
    segments_per_body: dict[str, int] = field(default_factory=dict)
    merged: dict[int, list[str]] = field(default_factory=dict)  # primitive id → bodies it spans

    @property
    def bodies_merged(self) -> int:
        return len(self.merged)


def score_primitives(
    segments: dict[str, np.ndarray],
    primitives: list[Primitive],
    delta: float = DELTA,
    scope: set[str] | None = None,
) -> Scores:
    """InlierIndex (Eq. 3.11) and OverlappingIndex (Eq. 3.12) of ``primitives`` against the
    labelled ground-truth points of the bodies in ``scope`` (default: all), and the
    primitive ↔ body maps (over all bodies)."""
    names = list(segments)
    if not names or not primitives:
        return Scores(0.0, 0.0, {}, {}, 0.0 if primitives else 1.0)
    cloud = np.concatenate([segments[n] for n in names])
    owner = np.concatenate([np.full(len(segments[n]), i) for i, n in enumerate(names)])
    sizes = np.array([len(segments[n]) for n in names])
    # the points by x: each primitive tests only those within its OBB's reach along x (an
    # episode's labelled cloud has millions, a primitive's box holds a few thousand)
    order = np.argsort(cloud[:, 0], kind="stable")
    xs = cloud[order, 0]
    covered = np.zeros((len(names), len(primitives)))
    jaccard = np.zeros((len(names), len(primitives)))
    bodies: dict[int, str] = {}
    merged: dict[int, list[str]] = {}
    for j, p in enumerate(primitives):
        near = order[slice(*np.searchsorted(xs, _x_reach(p, max(delta, OBB_MARGIN))))]
        points = cloud[near]
        excess = obb_excess(p, points)
        # explained by ψ: inside its OBB (grown by delta) and within delta of its surface
        candidates = np.flatnonzero(excess <= delta)
        explained = candidates[p.model.distance(points[candidates]) < delta]
        counts = np.bincount(owner[near[explained]], minlength=len(names))
        n_explained = len(explained)
        if n_explained:
            best = int(np.argmax(counts))
            if counts[best] > 0.5 * n_explained:
                bodies[p.id] = names[best]
            spanned = np.flatnonzero(counts >= MERGED_SHARE * n_explained)
            if len(spanned) >= 2:
                merged[p.id] = sorted(names[i] for i in spanned)
        inside = np.bincount(owner[near[excess <= OBB_MARGIN]], minlength=len(names))
        covered[:, j] = inside / np.maximum(sizes, 1)  # Inlier(G_i, ψ) = |G_i ∩ OBB(ψ)| / |G_i|
        union = sizes + n_explained - counts
        jaccard[:, j] = np.where(union > 0, counts / np.maximum(union, 1), 0.0)
    match = {n: primitives[int(np.argmax(covered[i]))].id for i, n in enumerate(names)}
    rows = [i for i, n in enumerate(names) if scope is None or n in scope] or list(
        range(len(names))
    )
    per_body: dict[str, int] = {}
    for b in bodies.values():
        per_body[b] = per_body.get(b, 0) + 1
    return Scores(
        inlier_index=float(covered[rows].max(axis=1).mean()),
        overlapping_index=float(jaccard[rows].max(axis=1).mean()),
        match=match,
        bodies=bodies,
        vertex_precision=len(bodies) / len(primitives),
        segments_per_body=dict(sorted(per_body.items())),
        merged=merged,
    )


def bodies_in_roi(gt: GroundTruth) -> set[str]:
    """Bodies whose box meets the region of interest (all of them when there is none)."""
    if gt.roi_min is None or gt.roi_max is None:
        return {o.name for o in gt.objects}
    centre, half = (gt.roi_min + gt.roi_max) / 2, (gt.roi_max - gt.roi_min) / 2
    out = set()
    for o in gt.objects:
        R, c = o.pose[:3, :3], o.pose[:3, 3]
        reach = np.abs(R) @ (o.size / 2)  # world-axis half extents of the body's box
        if np.all(np.abs(c - centre) <= half + reach):
            out.add(o.name)
    return out


@dataclass
class SupportScores:
    precision: float
    recall: float
    f1: float
    edges: list[tuple[str, str]]  # every judged perceived edge, unmapped ends as '#<id>'
    vertices: list[str]
    false_positives: list[tuple[str, str]] = field(default_factory=list)
    missed: list[tuple[str, str]] = field(default_factory=list)  # true edges not perceived


def edge_names(edges: list[tuple[int, int]], bodies: dict[int, str]) -> list[tuple[str, str]]:
    """Perceived edges (supporter id, supported id) as body names; an end that maps to no
    body is named '#<primitive id>'. Edges between the same two bodies are listed once."""
    out = {(bodies.get(s, f"#{s}"), bodies.get(t, f"#{t}")) for s, t in edges}
    return sorted(out)


def score_support(
    gt: GroundTruth,
    edges: list[tuple[int, int]],
    bodies: dict[int, str],
    scope: set[str] | None = None,
) -> SupportScores:
    """Eq. 4.14-4.16 on the support edges: perceived edges (supporter id, supported id) mapped
    through ``bodies``. Every edge counts: an end that maps to no body, or both ends on one
    body, make it a false positive (one with an end on no body wherever its other end is).
    Edges between two bodies of which one lies outside ``scope`` (default: the ROI's bodies)
    are not judged, and neither are ground-truth edges outside it. With no edge to find and
    none perceived the graph is right (1.0)."""
    scope = bodies_in_roi(gt) if scope is None else scope
    e_gt = {(a, b) for a, b in gt.support_edges if a in scope and b in scope}
    judged = set()
    for a, b in edge_names(edges, bodies):
        unmapped = a.startswith("#") or b.startswith("#")
        if not unmapped and (a not in scope or b not in scope):
            continue  # an edge of the scene outside the region of interest
        judged.add((a, b))  # an edge from a primitive of no body is wrong wherever it ends
    tp = len(judged & e_gt)
    if not judged and not e_gt:
        precision = recall = 1.0
    else:
        precision = tp / len(judged) if judged else 0.0
        recall = tp / len(e_gt) if e_gt else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    vertices = sorted({b for b in bodies.values() if b in scope})
    return SupportScores(precision, recall, f1, sorted(judged), vertices, sorted(judged - e_gt),
                         sorted(e_gt - judged))  # fmt: skip


def label_by_boxes(
    gt: GroundTruth, points: np.ndarray, margin: float = OBB_MARGIN
) -> dict[str, np.ndarray]:
    """Labelled ground-truth points from a world cloud (a running scene memory's registered
    cloud, for an outside evaluator that saw none of the frames): each point goes to the
    smallest ground-truth body whose box, grown by ``margin``, holds it (an object on a shelf
    board lies inside the shelf's box too), none to points in no box (the floor, walls of no
    body). Where a segmented frame is at hand, ``labelled_points`` is exact; this is as good
    as the boxes are tight (boxes, cylinders, spheres: their own; compounds: their bounds)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    best = np.full(len(points), -1)
    volume = np.full(len(points), np.inf)
    bodies = [o for o in gt.objects if o.name != "robot"]
    for i, o in enumerate(bodies):
        R, c = np.asarray(o.pose)[:3, :3], np.asarray(o.pose)[:3, 3]
        local = (points - c) @ R
        inside = np.all(np.abs(local) <= np.asarray(o.size) / 2 + margin, axis=1)
        v = float(np.prod(np.asarray(o.size) + 2 * margin))
        take = inside & (v < volume)
        best[take], volume[take] = i, v
    return {o.name: points[best == i] for i, o in enumerate(bodies) if np.any(best == i)}
