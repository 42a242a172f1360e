"""Top-down view sampling (thesis 4.2.2, Algorithms 3 and 4): Points of Interest from the
support graph, projected onto the view sphere with a saliency, spread to neighbouring views,
and inverted where the line of sight is blocked."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from schemas import SceneModel
from services.nbv.view_sphere import spherical

OCCUPIED = 2


@dataclass
class PoI:
    x: np.ndarray  # world point
    saliency: float
    azimuth: float  # from the sphere centre: where the view onto it lies


def edge_saliency(occ: int, n: int, lambda_s: float = 0.75) -> float:
    """Eq. 4.5: s = λ_s + (1 − λ_s)·cos(π/2 · occ(e)/n): an edge seen in every view scores λ_s,
    one seen rarely close to 1."""
    return lambda_s + (1 - lambda_s) * math.cos(math.pi / 2 * min(occ, n) / max(n, 1))


def largest_arc(azimuths: list[float]) -> tuple[float, float]:
    """(middle, width) of the largest gap between the azimuths of the previous views around the
    centre (GetLargestArc); the whole circle opposite the one view there is."""
    if not azimuths:
        return 0.0, 2 * math.pi
    a = np.sort(np.mod(azimuths, 2 * math.pi))
    gaps = np.diff(np.concatenate([a, [a[0] + 2 * math.pi]]))
    i = int(np.argmax(gaps))
    return float(np.mod(a[i] + gaps[i] / 2, 2 * math.pi)), float(gaps[i])


def _is_ground(p, root: int | None) -> bool:
    """The root and large level planes (floor, table tops) need no supporter."""
    if p.id == root:
        return True
    if p.model.kind != "plane" or abs(p.model.normal[2]) < math.cos(math.radians(15)):
        return False
    e = np.sort(p.obb.extent)[1:]
    return float(e[0] * e[1]) >= 0.2


def points_of_interest(
    scene: SceneModel, centre: np.ndarray, visited_xy: np.ndarray, lambda_s: float = 0.75
) -> list[PoI]:
    """Algorithm 3. Unsupported primitives: a PoI on the primitive towards the middle of the
    largest arc between the previous views, saliency 1. Support edges (B, A): a PoI between A
    and B with the saliency of Eq. 4.5."""
    prims = {p.id: p for p in scene.primitives}
    supporters: dict[int, list[tuple[int, int]]] = {i: [] for i in prims}
    for e in scene.support_edges:
        if e.supported in supporters and e.supporter in prims:
            supporters[e.supported].append((e.supporter, e.occ))
    azimuths = [math.atan2(y - centre[1], x - centre[0]) for x, y in visited_xy]
    middle, _ = largest_arc(azimuths)
    direction = np.array([math.cos(middle), math.sin(middle), 0.0])
    out = []
    for i, a in prims.items():
        ca = a.obb.center
        if not supporters[i]:
            if _is_ground(a, scene.root_id):
                continue
            # where the line from the centre towards the arc leaves the primitive's box
            along = np.abs(a.obb.rotation.T @ direction)
            exit_t = np.min(a.obb.extent / 2 / np.maximum(along, 1e-9))
            out.append(PoI(ca + direction * exit_t, 1.0, middle))
        for b, occ in supporters[i]:
            x = ca + (prims[b].obb.center - ca) / 2
            if _is_ground(prims[b], scene.root_id):
                x = ca - np.array([0, 0, a.obb.extent @ np.abs(a.obb.rotation[2]) / 2])
            az = math.atan2(x[1] - centre[1], x[0] - centre[0])
            out.append(PoI(x, edge_saliency(occ, max(scene.n_views, 1), lambda_s), az))
    return out


@njit(cache=True, nogil=True)
def _sight(states, origin, voxel, a, b, skip):
    """``line_of_sight``'s samples and test, step for step, compiled (a planning step checks
    hundreds of views: ~0.1 ms of numpy calls each)."""
    d = b - a
    length = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    u = d / length
    ts = np.arange(skip, length, voxel / 2)
    nx, ny, nz = states.shape
    for t in ts:
        i = np.int64(np.floor((a[0] + t * u[0] - origin[0]) / voxel))
        j = np.int64(np.floor((a[1] + t * u[1] - origin[1]) / voxel))
        k = np.int64(np.floor((a[2] + t * u[2] - origin[2]) / voxel))
        if 0 <= i < nx and 0 <= j < ny and 0 <= k < nz and states[i, j, k] == OCCUPIED:
            return False
    return True


def lines_of_sight(states, origin, voxel, a: np.ndarray, b: np.ndarray, skip: float):
    """``line_of_sight`` of each segment a[i] → b[i] (bool per row)."""
    a = np.ascontiguousarray(a, np.float64).reshape(-1, 3)
    b = np.ascontiguousarray(b, np.float64).reshape(-1, 3)
    origin, voxel, skip = np.asarray(origin, np.float64), float(voxel), float(skip)
    return np.array(
        [_sight(states, origin, voxel, p, q, skip) for p, q in zip(a, b, strict=True)], bool
    )


def line_of_sight(states, origin, voxel, a: np.ndarray, b: np.ndarray, skip: float) -> bool:
    """SingleRayCast + IsIntersectionFree: no occupied voxel on the segment a → b, ignoring the
    first ``skip`` metres (the PoI's own surface)."""
    d = b - a
    length = float(np.linalg.norm(d))
    ts = np.arange(skip, length, voxel / 2)
    k = np.floor((a + np.outer(ts, d / length) - origin) / voxel).astype(int)
    inside = np.all((k >= 0) & (k < states.shape), axis=1)
    k = k[inside]
    return not np.any(states[k[:, 0], k[:, 1], k[:, 2]] == OCCUPIED)


def saliency(
    t: np.ndarray,
    pois: list[PoI],
    theta: float,
    r: float,
    centre: np.ndarray,
    states,
    origin,
    voxel: float,
    spread: float = math.radians(25),
) -> tuple[np.ndarray, np.ndarray]:
    """Algorithm 4: each PoI projected onto the sphere at polar angle ``theta`` on its azimuth
    (the views it adds), with its saliency inverted when the line of sight from the PoI to the
    view is blocked; every view (``t`` and the added) takes the largest saliency of a PoI,
    decayed with the angle between them. Returns (all sphere points, their saliency)."""
    if not pois:
        return t, np.zeros(len(t))
    added = spherical(r, np.full(len(pois), theta), np.array([p.azimuth for p in pois]))
    s = np.array([p.saliency for p in pois])
    for i, p in enumerate(pois):
        if not line_of_sight(states, origin, voxel, p.x, centre + added[i], skip=0.05):
            s[i] = 1 - s[i]
    views = np.concatenate([t, added])
    unit = views / np.linalg.norm(views, axis=1, keepdims=True)
    poi_unit = added / np.linalg.norm(added, axis=1, keepdims=True)
    angle = np.arccos(np.clip(unit @ poi_unit.T, -1, 1))
    return views, (s[None, :] * np.exp(-((angle / spread) ** 2))).max(axis=1)
