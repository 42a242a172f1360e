"""The outlines of level surfaces (table tops, shelf boards, the tops of boxes), aligned in the
ground plane: what a frame from the far side of a table shares with the map.

From opposite sides a frame and the map share little but level surfaces, and point-to-plane
ICP cannot tell where along them the frame lies: a level surface's normal says nothing of x, y
or yaw, and the upright faces each side sees are different ones (a box's front and back). The
outlines of the level surfaces do: a table top's rectangle and the boxes' tops are seen whole
from either side. ``refine`` aligns the frame's outlines to the map's by point-to-point ICP in
x, y and yaw (a weighted 2-D Procrustes step, Tukey's loss coarse to fine), each point matched
to a map point at its height.

Level points are those within ``band`` of a height many points share (a peak of the heights'
histogram, ``bin`` wide), above the floor; a level point is on an outline where its neighbours
within ``radius`` at its height lie to one side of it (their mean offset beyond ``share`` of the
radius). Not by normals: near a table's near edge the normals tilt with the front face below
it and a normal test drops the last 1-2 cm of the top, so each side's outline recedes from its
own camera and the two disagree by 15-20 mm (measured on noise-free depth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from services.scene_memory.voxel_map import means, summarise


@dataclass(frozen=True)
class OutlineConfig:
    #: points are averaged on this voxel first (m)
    voxel: float = 0.01
    #: level surfaces: heights' histogram bins (m), a peak holds at least ``min_share`` of the
    #: points above ``above`` (and ``min_points``), its points lie within ``band`` of it
    bin: float = 0.005
    min_share: float = 0.01
    min_points: int = 50
    band: float = 0.008
    above: float = 0.1
    #: an outline point's neighbours within ``radius`` (m) lie to one side of it: their mean
    #: offset is beyond ``share`` of the radius
    radius: float = 0.03
    share: float = 0.3
    #: ICP: a match farther than ``distance`` is none; Tukey's k (m) of each stage, coarse to
    #: fine (a 3 cm offset is past a 2 cm kernel: the short edges that hold the slide along
    #: the long ones would weigh nothing), at most ``iterations`` each
    distance: float = 0.05
    kernels: tuple[float, ...] = (0.03, 0.02)
    iterations: int = 40
    #: heights weigh this much more than x and y in the matching (a table top's outline must
    #: not be matched to a box's 5 cm above it)
    height_scale: float = 3.0


def level_points(points: np.ndarray, c: OutlineConfig) -> np.ndarray:
    """The points (world, z up) on level surfaces above the floor, averaged on ``c.voxel``."""
    if len(points) == 0:
        return np.zeros((0, 3))
    index, stats = summarise(np.ascontiguousarray(points, np.float64), c.voxel)
    p = means(index, stats, c.voxel)
    p = p[p[:, 2] > c.above]
    if len(p) < c.min_points:
        return p[:0]
    edges = np.arange(c.above, p[:, 2].max() + 2 * c.bin, c.bin)
    hist, edges = np.histogram(p[:, 2], bins=edges)
    enough = max(c.min_points, c.min_share * len(p))
    padded = np.concatenate([[-1], hist, [-1]])
    peak = (hist >= padded[:-2]) & (hist >= padded[2:]) & (hist >= enough)
    heights = (edges[:-1] + edges[1:])[peak] / 2
    if not len(heights):
        return p[:0]
    near = np.min(np.abs(p[:, 2, None] - heights[None, :]), axis=1) < c.band
    return p[near]


def outline(points: np.ndarray, c: OutlineConfig | None = None) -> np.ndarray:
    """The points on the outlines of the level surfaces of ``points`` (world, z up), (m, 3)."""
    c = c or OutlineConfig()
    q = level_points(points, c)
    if len(q) < 4:
        return q
    scale = np.array([1.0, 1.0, c.height_scale])
    k = min(len(q), int(4 * (c.radius / c.voxel) ** 2) + 1)
    distance, j = cKDTree(q * scale).query(q * scale, k=k, distance_upper_bound=c.radius)
    found = np.isfinite(distance)
    j = np.where(found, j, 0)
    offsets = (q[j, :2] - q[:, None, :2]) * found[..., None]
    count = found.sum(axis=1)
    mean = offsets.sum(axis=1) / np.maximum(count, 1)[:, None]
    edge = (count >= 4) & (np.linalg.norm(mean, axis=1) > c.share * c.radius)
    return q[edge]


def refine(
    source: np.ndarray, target: np.ndarray, c: OutlineConfig | None = None
) -> tuple[np.ndarray, float]:
    """The planar correction (4×4, world: a turn about the vertical and a shift) that aligns the
    outline ``source`` to ``target``, and the Tukey weight of the matches at the end (how much
    of the outline agrees; 0 when too little matched to solve)."""
    c = c or OutlineConfig()
    C = np.eye(4)
    if len(source) < 10 or len(target) < 10:
        return C, 0.0
    scale = np.array([1.0, 1.0, c.height_scale])
    tree = cKDTree(target * scale)
    weight = 0.0
    for kernel in c.kernels:
        for _ in range(c.iterations):
            X = source @ C[:3, :3].T + C[:3, 3]
            d, j = tree.query(X * scale, distance_upper_bound=c.distance)
            ok = np.isfinite(d)
            if ok.sum() < 10:
                return np.eye(4), 0.0
            x, y = X[ok, :2], target[j[ok], :2]
            r = np.linalg.norm(x - y, axis=1)
            w = np.where(r < kernel, (1 - (r / kernel) ** 2) ** 2, 0.0)
            weight = float(w.sum())
            if weight < 5:
                return np.eye(4), 0.0
            mx, my = w @ x / weight, w @ y / weight
            H = ((x - mx) * w[:, None]).T @ (y - my)
            a = math.atan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
            R = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
            step = np.eye(4)
            step[:2, :2] = R
            step[:2, 3] = my - R @ mx
            C = step @ C
            if abs(a) < 1e-6 and np.linalg.norm(step[:2, 3]) < 1e-5:
                break
    return C, weight
