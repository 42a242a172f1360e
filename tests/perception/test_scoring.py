"""score_primitives tests each primitive only against the points within its box's reach along
x (an episode's labelled cloud has millions): the scores must be those of the definitions
(Eq. 3.8, 3.10-3.12) evaluated over every point."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from experiments import evaluation
from schemas import BoxModel, CylinderModel, Obb, PlaneModel, Primitive, SphereModel


def _primitive(pid: int, rng: np.random.Generator) -> Primitive:
    R = Rotation.random(random_state=rng).as_matrix()
    c = rng.uniform(-1, 1, 3)
    extent = rng.uniform(0.05, 0.8, 3)
    kind = pid % 4
    model = [
        PlaneModel(normal=R[:, 2], d=-float(R[:, 2] @ c)),
        CylinderModel(center=c, axis=R[:, 2], radius=float(extent[0] / 2), height=extent[2]),
        SphereModel(center=c, radius=float(extent.min() / 2)),
        BoxModel(center=c, rotation=R, extent=extent),
    ][kind]
    obb = Obb(center=c, rotation=R, extent=extent)
    return Primitive(id=pid, model=model, obb=obb, inlier_count=1,
                     inliers=np.zeros((0, 3), np.float32))  # fmt: skip


def _by_definition(segments, primitives, delta=evaluation.DELTA):
    """Inlier, Jaccard and the body maps over every point, one body and primitive at a time."""
    names = list(segments)

    def in_box(p, pts, margin):
        local = (pts - p.obb.center) @ p.obb.rotation
        return np.all(np.abs(local) <= p.obb.extent / 2 + margin, axis=1)

    cover = np.array([[in_box(p, segments[n], evaluation.OBB_MARGIN).mean() for p in primitives]
                      for n in names])  # fmt: skip
    jac, bodies = np.zeros_like(cover), {}
    for j, p in enumerate(primitives):
        expl = {n: in_box(p, segments[n], delta) & (p.model.distance(segments[n]) < delta)
                for n in names}  # fmt: skip
        total = sum(int(e.sum()) for e in expl.values())
        for i, n in enumerate(names):
            k = int(expl[n].sum())
            jac[i, j] = k / (len(segments[n]) + total - k)
            if total and k > 0.5 * total:
                bodies[p.id] = n
    return cover.max(axis=1).mean(), jac.max(axis=1).mean(), bodies


def test_scores_equal_the_definitions_over_every_point():
    rng = np.random.default_rng(7)
    primitives = [_primitive(i, rng) for i in range(24)]
    segments = {}
    for i, p in enumerate(primitives[:12]):  # bodies: points on and around 12 of them
        local = rng.uniform(-0.6, 0.6, (4000, 3)) * p.obb.extent
        segments[f"body{i}"] = local @ p.obb.rotation.T + p.obb.center
    segments["clutter"] = rng.uniform(-1.6, 1.6, (20000, 3))
    scores = evaluation.score_primitives(segments, primitives)
    inlier_index, overlapping_index, bodies = _by_definition(segments, primitives)
    assert 0.05 < inlier_index < 1 and 0.001 < overlapping_index < 1  # not a trivial case
    assert scores.inlier_index == inlier_index
    assert scores.overlapping_index == overlapping_index
    assert scores.bodies == bodies and len(bodies) >= 6
