"""Algorithm 1 (Geometric Primitive Extraction) per segment, then boxes from orthogonal planes.

For each segment P_i, while τ_min ≤ |P_i|: fit a plane, a cylinder and a sphere by RANSAC, keep
the one with most inliers (a curved model must beat the plane clearly and really be curved),
keep the largest connected cluster of its inliers (Euclidean clustering, on the image grid),
compute its geometric properties and remove it from P_i. Segments above τ_max points are fitted
on a random τ_max of them; inliers are always counted on all. Afterwards, two or three mutually
orthogonal, touching planes of one segment become a box (thesis 3.1: cuboids).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from services.perception import kernels, ransac
from services.perception.cloud import OrganizedCloud
from services.perception.obb import Box, axis_box, cross, intersect, plane_box
from services.perception.pointset import PointSet

#: what Algorithm 1 runs on: a depth image's grid, or an unorganized cloud's neighbour graph
Cloud = OrganizedCloud | PointSet


@dataclass
class ExtractionConfig:
    tau_min: int = 60  # fewest inliers of a primitive (grid points)
    share_min: float = 0.05  # ... and at least this share of its segment (leftovers stay out)
    tau_max: int = 4_000  # most points one fit looks at (inliers are counted on all)
    dist_base: float = 0.004  # inlier distance d(z) = dist_base + dist_quad·z² (m)
    dist_quad: float = 0.004
    angle_deg: float = 25.0  # largest normal deviation of an inlier at 1 m ...
    angle_per_m: float = 12.0  # ... growing with distance as the normals get noisier
    angle_max: float = 60.0
    radius_min: float = 0.01
    radius_max: float = 0.25
    curved_gain: float = 1.1  # a cylinder / sphere must have this many times the plane's inliers
    two_plane_share: float = 0.8  # two planes explaining this share make a segment piecewise planar
    min_arc_deg: float = 45.0  # a cylinder's normals must sweep this arc around its axis
    min_sphere_spread_deg: float = 15.0
    box_orthogonal_deg: float = 12.0
    thin_face: float = 0.06  # m: a face narrower than this ...
    thin_orthogonal_deg: float = 25.0  # ... may be this far from orthogonal
    box_touch: float = 0.02
    box_edge_ratio: float = 0.6  # faces of a box: lengths along the common edge agree this well
    box_concave: float = 0.005  # m: ... and each face's middle lies behind the other (convex)
    face_fill: float = 0.4  # ... and each face's points cover this much of its rectangle
    flat_ratio: float = 3.0  # a plane's OBB: middle extent ≥ this × its band (0: any) ...
    flat_band: float = 0.015  # ... where its inliers' band is thicker than this (m)
    frame_size: float = 0.3  # m: a plane this large (middle extent) ...
    frame_fill: float = 0.25  # ... whose inliers fill less of its rectangle is a frame (0: off)


@dataclass
class Extracted:
    """One primitive ψ with its inlier grid pixels."""

    kind: str
    pixels: np.ndarray  # flat indices into the grid
    points: np.ndarray  # (n, 3) inlier points
    box: Box
    segment: int
    normal: np.ndarray | None = None  # plane
    d: float = 0.0
    center: np.ndarray | None = None  # cylinder, sphere, box
    axis: np.ndarray | None = None  # cylinder
    radius: float = 0.0
    rotation: np.ndarray | None = None  # box
    extent: np.ndarray | None = None  # box
    height: float = 0.0  # cylinder


def _member(pixels: np.ndarray, of: np.ndarray, size: int) -> np.ndarray:
    """Which of ``pixels`` (flat grid indices) are among ``of``: a mask over the ``size``
    grid points, not np.isin's sort (a tenth of the time on a segment's pixels)."""
    grid = np.zeros(size, bool)
    grid[of] = True
    return grid[pixels]


def _rows(A: np.ndarray, index: np.ndarray) -> np.ndarray:
    """``A[index].astype(float64)`` of an (n, 3) array by np.take (a third of the time of
    fancy indexing on a segment's tens of thousands of rows)."""
    return np.take(A, index, axis=0).astype(np.float64, copy=False)


def _largest_cluster(pixels: np.ndarray, cloud: Cloud) -> np.ndarray:
    """The largest connected component of the given pixels: Euclidean clustering where
    neighbours are pixels (8-connected on the grid) or the point set's graph neighbours."""
    if len(pixels) == 0:
        return pixels
    own, n = cloud.labels(pixels)
    if n <= 1:
        return pixels
    return pixels[own == np.argmax(np.bincount(own))]


def _make(
    fit: ransac.Fit, pixels: np.ndarray, points: np.ndarray, segment: int, camera: np.ndarray
) -> Extracted:
    if fit.kind == "plane":
        normal, d = fit.normal, fit.d
        if normal @ (camera - points.mean(0)) < 0:  # a plane's normal faces the camera
            normal, d = -normal, -d
        return Extracted(
            "plane", pixels, points, plane_box(points, normal), segment, normal=normal, d=d
        )
    if fit.kind == "cylinder":
        box = axis_box(points, fit.axis, fit.center, fit.radius)
        return Extracted(
            "cylinder",
            pixels,
            points,
            box,
            segment,
            center=box.center,
            axis=fit.axis,
            radius=fit.radius,
            height=float(box.extent[2]),
        )
    box = Box(fit.center.copy(), np.eye(3), np.full(3, 2 * fit.radius))
    return Extracted("sphere", pixels, points, box, segment, center=fit.center, radius=fit.radius)


def _cap(
    fit: ransac.Fit, X: np.ndarray, N: np.ndarray, inliers: np.ndarray, dist: float
) -> np.ndarray:
    """Points of a cylinder's end caps: within the radius of the axis, just beyond the side's
    span, normals along the axis."""
    v = X - fit.center
    t = v @ fit.axis
    radial = np.linalg.norm(v - np.outer(t, fit.axis), axis=1)
    lo, hi = t[inliers].min(), t[inliers].max()
    near_end = (
        (t > lo - 2 * dist) & (t < hi + 2 * dist) & ((t < lo + 2 * dist) | (t > hi - 2 * dist))
    )
    return near_end & (radial < fit.radius + dist) & (np.abs(N @ fit.axis) > 0.8)


def extract_segment(
    cloud: Cloud,
    pixels: np.ndarray,
    segment: int,
    config: ExtractionConfig,
    rng: np.random.Generator,
) -> list[Extracted]:
    """Algorithm 1 on one segment (its flat grid pixel indices). After each primitive the rest
    of the segment is split into its connected parts (Euclidean clustering once the dominant
    plane is gone: an object whose crease with the table was not closed stands apart again),
    and each part goes on on its own."""
    P = cloud.points.reshape(-1, 3)
    Nn = cloud.normals.reshape(-1, 3)
    out: list[Extracted] = []
    parts = [pixels]
    while parts:
        remaining = parts.pop()
        least = max(config.tau_min, int(config.share_min * len(remaining)))
        if len(remaining) < least:
            continue
        # (np.take: a third of the time of fancy indexing rows of an (n, 3) array)
        X, N = _rows(P, remaining), _rows(Nn, remaining)
        sample = np.arange(len(X))
        if len(X) > config.tau_max:
            sample = rng.choice(len(X), config.tau_max, replace=False)
        Xs, Ns = _rows(X, sample), _rows(N, sample)
        cam_dist = cloud.viewing_distance(remaining[sample[:200]])
        dist = config.dist_base + config.dist_quad * cam_dist**2
        angle = config.angle_deg + config.angle_per_m * max(0.0, cam_dist - 1.0)
        cos_min = np.cos(np.radians(min(angle, config.angle_max)))
        plane = ransac.fit_plane(Xs, Ns, rng, dist, cos_min)
        fits = [plane]
        # a curved model must have curved_gain × the plane's inliers: impossible once the plane
        # explains more than 1 / curved_gain of the segment
        plane_share = plane.count / len(sample) if plane is not None else 0.0
        two_planes = 0  # points a second plane explains beyond the first (a box's faces)
        if 0 < plane_share * config.curved_gain < 1.0:
            rest = ~plane.inliers
            second = ransac.fit_plane(Xs[rest], Ns[rest], rng, dist, cos_min, 24)
            if second is not None:
                two_planes = plane.count + second.count
                if two_planes >= config.two_plane_share * len(sample):
                    plane_share = 1.0  # piecewise planar (a box): no curved fit needed
        if plane_share * config.curved_gain < 1.0:
            fits.append(
                ransac.fit_cylinder(
                    Xs, Ns, rng, dist, cos_min, config.radius_min, config.radius_max
                )
            )
            fits.append(
                ransac.fit_sphere(Xs, Ns, rng, dist, cos_min, config.radius_min, config.radius_max)
            )
        best = _choose(fits, X, N, dist, cos_min, config, two_planes * len(X) / len(sample))
        if best is None or best.count < least:
            continue
        # membership: the normal-tested inliers, grown by one grid step to the points that fit
        # by distance alone (near silhouettes the normals are smoothed across the edge and
        # the normal test would shave the primitive's border off)
        keep = best.inliers | (cloud.near(remaining, best.inliers) & (_distances(best, X) < dist))
        if best.kind == "cylinder":
            keep = keep | _cap(best, X, N, best.inliers, dist)
        cluster = _largest_cluster(remaining[keep], cloud)
        if len(cluster) < least:
            continue
        if best.kind == "cylinder":  # the box spans the side only: caps do not move the ends
            side = _member(cluster, remaining[_distances(best, X) < dist], cloud.size)
            prim = _make(
                best,
                cluster[side],
                _rows(P, cluster[side]),
                segment,
                cloud.viewer(cluster[side]),
            )
            prim.pixels, prim.points = cluster, _rows(P, cluster)
        else:
            prim = _make(best, cluster, _rows(P, cluster), segment, cloud.viewer(cluster))
        if not _flat_enough(prim, config) or _a_frame(prim, config):
            # a band of noisy depth, or the border strips of a rectangle: not a surface; what
            # it held stays unexplained
            remaining = remaining[~_member(remaining, cluster, cloud.size)]
            continue
        out.append(prim)
        remaining = remaining[~_member(remaining, cluster, cloud.size)]
        parts += [p for p in _components(remaining, cloud) if len(p) >= config.tau_min]
    return out


def _flat_enough(prim: Extracted, config: ExtractionConfig) -> bool:
    """A plane is one where its inliers' band is thin beside its size: where the band (the
    10th to 90th percentile of their distances to the plane) is thicker than ``flat_band``,
    its OBB's middle extent must be ``flat_ratio`` times the band. Far from a
    structured-light camera the inlier distance d(z) is a few cm (depth comes in 18 mm steps
    at 2.5 m), and a patch of clutter a few cm across fits "a plane" at any tilt. (Near it
    the band is mm thin, and a book's 3 cm side is a face; the OBB's own thickness is no
    measure: a face's box takes in a strip of its neighbour along the edge.)"""
    if prim.kind != "plane" or config.flat_ratio <= 0:
        return True
    lo, hi = kernels.plane_band(prim.points, prim.normal, float(prim.d), 10.0, 90.0)
    band = hi - lo
    middle = np.sort(prim.box.extent)[1]
    return bool(band <= config.flat_band or middle >= config.flat_ratio * band)


def _a_frame(prim: Extracted, config: ExtractionConfig) -> bool:
    """A large plane whose inliers cover little of its rectangle (``fill`` under
    ``frame_fill``, its middle extent ``frame_size`` or more): the front edges of an open
    shelf's boards and side panels, coplanar and joined at the corners, a table's front edge
    with the legs below it. Its rectangle spans a hole, and it seemed to hold up whatever
    stood at its edges. (Surfaces measured at the start views of the built-in scenes fill
    0.43 or more, with the objects' shadows; the shelf's frame 0.15.)"""
    if prim.kind != "plane" or config.frame_fill <= 0:
        return False
    return bool(np.sort(prim.box.extent)[1] >= config.frame_size and fill(prim) < config.frame_fill)


def _components(pixels: np.ndarray, cloud: Cloud) -> list[np.ndarray]:
    """The connected components of the given pixels (8-connected on the grid)."""
    if len(pixels) == 0:
        return []
    own, n = cloud.labels(pixels)
    order = np.argsort(own, kind="stable")
    bounds = np.searchsorted(own[order], np.arange(1, n + 2))
    return [pixels[order[bounds[k] : bounds[k + 1]]] for k in range(n)]


def _near(pixels: np.ndarray, mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Which of ``pixels`` are within one grid step of the ``mask``-ed ones (compiled)."""
    return kernels.near(pixels, mask, shape[1])


def _near_numpy(pixels: np.ndarray, mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``_near`` by scipy's dilation (the reference the compiled one is tested against)."""
    rows, cols = np.divmod(pixels, shape[1])
    r0, c0 = rows.min() - 1, cols.min() - 1
    grid = np.zeros((rows.max() - r0 + 2, cols.max() - c0 + 2), bool)
    grid[rows[mask] - r0, cols[mask] - c0] = True
    grid = ndimage.binary_dilation(grid, structure=np.ones((3, 3), bool))
    return grid[rows - r0, cols - c0]


def _distances(fit: ransac.Fit, X: np.ndarray) -> np.ndarray:
    if fit.kind == "plane":
        return np.abs(X @ fit.normal + fit.d)
    if fit.kind == "cylinder":
        return ransac.cylinder_residuals(X, X, fit.center, fit.axis, fit.radius)[0]
    return np.abs(np.linalg.norm(X - fit.center, axis=1) - fit.radius)


def _choose(
    fits, X, N, dist, cos_min, config: ExtractionConfig, two_planes: float = 0.0
) -> ransac.Fit | None:
    """Most inliers on the whole segment. A curved model must really be curved and beat the
    plane clearly — and beat two planes together where two explain the segment (a box)."""
    scored: list[ransac.Fit] = []
    for fit in fits:
        if fit is None:
            continue
        if fit.kind == "plane":
            fit.inliers = kernels.plane_inliers(X, N, fit.normal, fit.d, dist, cos_min)
        elif fit.kind == "cylinder":
            fit.inliers = kernels.cylinder_inliers(X, N, fit.center, fit.axis, fit.radius, dist,
                                                   cos_min)  # fmt: skip
        else:
            fit.inliers = kernels.sphere_inliers(X, N, fit.center, fit.radius, dist, cos_min)
        if (
            fit.kind == "cylinder"
            and ransac.cylinder_arc(np.compress(fit.inliers, N, axis=0), fit.axis)
            < config.min_arc_deg
        ):
            continue
        if (
            fit.kind == "sphere"
            and ransac.sphere_spread(np.compress(fit.inliers, N, axis=0))
            < config.min_sphere_spread_deg
        ):
            continue
        scored.append(fit)
    plane = next((f.count for f in scored if f.kind == "plane"), 0)
    bar = max(config.curved_gain * plane, two_planes)
    candidates = [f for f in scored if f.kind == "plane" or f.count >= bar]
    return max(candidates, key=lambda f: f.count, default=None)


def _box_from_faces(faces: list[Extracted], points: np.ndarray, R: np.ndarray) -> Box:
    """Each seen face fixes its side of the box at its fitted plane (noise averages out); the
    other sides come from the farthest points."""
    local = points @ R
    lo, hi = local.min(0), local.max(0)
    for f in faces:
        k = int(np.argmax(np.abs(R.T @ f.normal)))
        offset = float(np.mean(f.points @ R[:, k]))
        if f.normal @ R[:, k] > 0:  # visible faces' normals point out of the box
            hi[k] = offset
        else:
            lo[k] = offset
    return Box(R @ ((lo + hi) / 2), R, hi - lo)


def _share_an_edge(a: Extracted, b: Extracted, config: ExtractionConfig) -> bool:
    """Two faces of one box are about as long along their common edge (a table top and the
    front of a crate standing on it are not)."""
    edge = cross(a.normal, b.normal)
    edge /= np.linalg.norm(edge)
    la, lb = np.ptp(a.points @ edge), np.ptp(b.points @ edge)
    return min(la, lb) >= config.box_edge_ratio * max(la, lb)


def fill(p: Extracted, cell: float = 0.02) -> float:
    """How much of its rectangle a plane's inliers cover (cells of ``cell`` metres with a
    point, over all cells of the rectangle): about 1 for a face of a box, little for a
    table's front edge and the front legs below it, coplanar within the noise far away."""
    R = p.box.rotation
    k = int(np.argmax(np.abs(R.T @ p.normal)))
    axes = [m for m in range(3) if m != k]
    uv = (p.points - p.box.center) @ R[:, axes]
    shape = np.maximum(1, np.ceil(p.box.extent[axes] / cell)).astype(int)
    ij = np.clip(((uv + p.box.extent[axes] / 2) / cell).astype(int), 0, shape - 1)
    cells = np.zeros(int(np.prod(shape)), bool)  # the occupied cells, not np.unique's sort
    cells[ij[:, 0] * shape[1] + ij[:, 1]] = True
    return int(np.count_nonzero(cells)) / float(np.prod(shape))


def _sin_orthogonal(wa: float, wb: float, config: ExtractionConfig) -> float:
    """How far from orthogonal two faces of a box may be fitted, by their narrower in-plane
    extents: a thin face (a plank's edge, a few centimetres across) has a noisy normal, so
    more for it."""
    thin = min(wa, wb) < config.thin_face
    return math.sin(math.radians(config.thin_orthogonal_deg if thin else config.box_orthogonal_deg))


def _convex(a: Extracted, b: Extracted, ca: np.ndarray, cb: np.ndarray, tol: float) -> bool:
    """Two faces of one box each lie behind the other's plane (``ca``, ``cb``: their inliers'
    means; normals face the camera, so out of a box): a box is convex. The inside of a
    shelf (a board and a side panel), a table top and the wall behind it meet at a concave
    edge and are no box."""
    return float(a.normal @ cb) + a.d < tol and float(b.normal @ ca) + b.d < tol


def _width(p: Extracted) -> float:
    """The narrower in-plane extent of a plane."""
    k = int(np.argmax(np.abs(p.box.rotation.T @ p.normal)))
    return float(np.delete(p.box.extent, k).min())


def assemble_boxes(prims: list[Extracted], config: ExtractionConfig) -> list[Extracted]:
    """Two or three mutually orthogonal, touching planes of one segment become one box;
    only planes that fill their rectangle can be faces of one."""
    out = [p for p in prims if p.kind != "plane"]
    planes = [p for p in prims if p.kind == "plane"]
    fills: dict[int, float] = {}  # computed when a pair would make a box: most never do

    def face(k: int) -> bool:
        if k not in fills:
            fills[k] = fill(planes[k])
        return fills[k] >= config.face_fill  # the others stay planes

    widths = [_width(p) for p in planes]  # once per plane, not per pair
    centres = [p.points.mean(axis=0) for p in planes]
    by_segment: dict[int, list[int]] = {}
    for k, p in enumerate(planes):
        by_segment.setdefault(p.segment, []).append(k)
    used = [False] * len(planes)
    for i, a in enumerate(planes):
        if used[i]:
            continue
        group = [i]
        for j in by_segment[a.segment]:  # in index order, as over all planes
            if j == i or used[j]:
                continue
            b = planes[j]
            orthogonal = all(
                abs(float(planes[k].normal @ b.normal))
                < _sin_orthogonal(widths[k], widths[j], config)
                for k in group
            )
            if (
                orthogonal
                and any(intersect(planes[k].box, b.box, config.box_touch) for k in group)
                and all(_share_an_edge(planes[k], b, config) for k in group)
                and all(
                    _convex(planes[k], b, centres[k], centres[j], config.box_concave) for k in group
                )
                and face(i)
                and face(j)
            ):
                group.append(j)
            if len(group) == 3:
                break
        if len(group) == 1:
            continue
        for k in group:
            used[k] = True
        faces = sorted((planes[k] for k in group), key=lambda p: -len(p.pixels))
        a1 = faces[0].normal
        a2 = faces[1].normal - (faces[1].normal @ a1) * a1
        a2 /= np.linalg.norm(a2)
        R = np.column_stack([a1, a2, cross(a1, a2)])
        points = np.concatenate([f.points for f in faces])
        box = _box_from_faces(faces, points, R)
        out.append(
            Extracted(
                "box",
                np.concatenate([f.pixels for f in faces]),
                points,
                box,
                a.segment,
                center=box.center,
                rotation=box.rotation,
                extent=box.extent,
            )
        )
    out += [p for k, p in enumerate(planes) if not used[k]]
    return out
