"""An unorganized world-frame cloud: what ``pc`` fusion perceives (thesis 3.3.1, Table 3.1).

The scene memory merges every registered view into one cloud, voxel-downsampled; the points of
many cameras have no image grid, so what the organized cloud gets from its pixels comes from a
neighbour graph here: two points are neighbours within ``radius`` (2 voxels: a surface sampled
at 1 cm stays connected, a gap of a few centimetres parts it). Normals are the smallest
principal axis of each point's neighbourhood, turned towards the camera that saw the point
(its *viewpoint*); segments are the connected components of the graph once the points on
concave creases are taken out (LCCP's convexity test, as on the grid); Euclidean clustering of
a primitive's inliers is connected components of the graph among them. Algorithm 1 itself
(``primitives.extract_segment``) is the same code for both clouds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree


@dataclass
class PointSet:
    """Per-point arrays of an unorganized cloud (n points), and its neighbour graph."""

    points: np.ndarray  # (n, 3) float32 world coordinates
    normals: np.ndarray  # (n, 3) float32 unit normals facing each point's viewpoint
    valid: np.ndarray  # (n,) bool, all True (the organized cloud's mask, for the counts)
    colours: np.ndarray  # (n, 3) uint8
    viewpoints: np.ndarray  # (n, 3) float32: the optical centre each point was seen from
    graph: sparse.csr_matrix  # (n, n) symmetric neighbour graph, no self loops
    camera_centre: np.ndarray  # (3,) the latest camera (the robot's head, for affordances)

    @property
    def shape(self) -> tuple[int]:
        return (len(self.points),)

    @property
    def size(self) -> int:
        return len(self.points)

    def labels(self, pixels: np.ndarray) -> tuple[np.ndarray, int]:
        """Connected components of the graph among ``pixels`` (point indices): each one's
        label (1 … k, in the order of each component's first point) and k."""
        if len(pixels) == 0:
            return np.zeros(0, np.int64), 0
        sub = self.graph[pixels][:, pixels]
        k, own = connected_components(sub, directed=False)
        # number components by their first point, as the grid's raster order does
        _, first = np.unique(own, return_index=True)
        rank = np.empty(k, np.int64)
        rank[np.argsort(first)] = np.arange(1, k + 1)
        return rank[own], k

    def near(self, pixels: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Which of ``pixels`` are ``mask``-ed or neighbours of a ``mask``-ed one."""
        marked = np.zeros(self.size, np.float32)
        marked[pixels[mask]] = 1.0
        reached = (self.graph @ marked) > 0
        return reached[pixels] | mask

    def viewing_distance(self, indices: np.ndarray) -> float:
        """Median distance from the points to the cameras that saw them (the noise scale)."""
        d = self.points[indices].astype(np.float64) - self.viewpoints[indices]
        return float(np.median(np.linalg.norm(d, axis=1)))

    def viewer(self, indices: np.ndarray) -> np.ndarray:
        """Where the points were seen from, on average (a plane's normal faces it)."""
        return self.viewpoints[indices].astype(np.float64).mean(0)


def neighbour_graph(points: np.ndarray, radius: float) -> sparse.csr_matrix:
    """Symmetric boolean adjacency of the points within ``radius`` of each other."""
    n = len(points)
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    data = np.ones(2 * len(pairs), np.float32)
    return sparse.csr_matrix((data, (np.concatenate([i, j]), np.concatenate([j, i]))), shape=(n, n))


def pca_normals(
    points: np.ndarray, graph: sparse.csr_matrix, viewpoints: np.ndarray, least: int = 5
) -> np.ndarray:
    """Unit normals (n, 3) float32: the smallest principal axis of each point with its
    neighbours, facing its viewpoint; 0 where fewer than ``least`` points make it up."""
    P = points.astype(np.float64)
    A = graph + sparse.identity(len(P), format="csr", dtype=np.float32)
    count = np.asarray(A.sum(axis=1)).ravel()
    mean = (A @ P) / count[:, None]
    outer = (P[:, :, None] * P[:, None, :]).reshape(-1, 9)
    cov = (A @ outer).reshape(-1, 3, 3) / count[:, None, None]
    cov -= mean[:, :, None] * mean[:, None, :]
    _, vectors = np.linalg.eigh(cov)
    normal = vectors[:, :, 0]
    flip = np.einsum("ij,ij->i", normal, viewpoints - P) < 0
    normal[flip] *= -1
    normal[count < least] = 0
    return normal.astype(np.float32)


def point_set(
    points: np.ndarray,
    viewpoints: np.ndarray,
    colours: np.ndarray | None = None,
    camera_centre: np.ndarray | None = None,
    radius: float = 0.02,
) -> PointSet:
    """The point set of a world cloud (``viewpoints``: the optical centre each point was seen
    from, one per point or one for all), its neighbour graph within ``radius`` and its
    normals."""
    P = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
    V = np.broadcast_to(np.asarray(viewpoints, np.float32), P.shape).copy()
    graph = neighbour_graph(P, radius)
    normals = pca_normals(P, graph, V)
    C = np.zeros((len(P), 3), np.uint8) if colours is None else np.asarray(colours, np.uint8)
    centre = V.mean(0) if camera_centre is None and len(V) else camera_centre
    return PointSet(P, normals, np.ones(len(P), bool), C, V, graph,
                    np.asarray(centre if centre is not None else np.zeros(3), float))  # fmt: skip


def creases(ps: PointSet, cos_crease: float) -> np.ndarray:
    """(n,) bool: points on a concave crease: a neighbour's normal differs by more than the
    crease angle and (n_i − n_j)·(p_i − p_j) < 0 (LCCP's convexity test), both ends marked."""
    coo = sparse.triu(ps.graph, k=1).tocoo()
    i, j = coo.row, coo.col
    Ni, Nj = ps.normals[i].astype(np.float64), ps.normals[j].astype(np.float64)
    known = np.any(Ni != 0, axis=1) & np.any(Nj != 0, axis=1)
    bent = np.einsum("ij,ij->i", Ni, Nj) < cos_crease
    dP = ps.points[i].astype(np.float64) - ps.points[j]
    concave = np.einsum("ij,ij->i", Ni - Nj, dP) < 0
    cut = known & bent & concave
    out = np.zeros(ps.size, bool)
    out[i[cut]] = True
    out[j[cut]] = True
    return out


def segment_points(
    ps: PointSet, min_size: int = 30, crease_deg: float = 30.0
) -> tuple[np.ndarray, int]:
    """Labels (n,) int32, -1 outside every region, and the number of regions (each at least
    ``min_size`` points), largest first: the graph's connected components once the points on
    concave creases are out. A crease's points then join the region of their nearest
    neighbour off it: the normals, averaged over 2 cm, bend over a band that wide on both
    sides, and without it a cylinder would end 2 cm above the box it stands on."""
    crease = creases(ps, float(np.cos(np.radians(crease_deg))))
    labels = np.full(ps.size, -1, np.int32)
    keep = np.flatnonzero(~crease)
    if len(keep) == 0:
        return labels, 0
    k, own = connected_components(ps.graph[keep][:, keep], directed=False)
    sizes = np.bincount(own, minlength=k)
    order = np.argsort(-sizes, kind="stable")
    order = order[sizes[order] >= min_size]
    remap = np.full(k, -1, np.int32)
    remap[order] = np.arange(len(order), dtype=np.int32)
    labels[keep] = remap[own]
    # the crease's points: to the region of the nearest labelled neighbour (a few passes:
    # a band two points wide is reached from both sides)
    waiting = np.flatnonzero(crease)
    for _ in range(4):
        coo = ps.graph[waiting].tocoo()
        rows, cols = waiting[coo.row], coo.col
        ok = labels[cols] >= 0
        rows, cols = rows[ok], cols[ok]
        if len(rows) == 0:
            break
        d = np.linalg.norm(ps.points[rows] - ps.points[cols], axis=1)
        first = np.lexsort((d, rows))
        rows, cols = rows[first], cols[first]
        head = np.r_[True, rows[1:] != rows[:-1]]
        labels[rows[head]] = labels[cols[head]]
        waiting = waiting[labels[waiting] < 0]
        if len(waiting) == 0:
            break
    return labels, len(order)
