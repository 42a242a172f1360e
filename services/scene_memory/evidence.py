"""Negative evidence for the spatio-temporal memory (thesis 3.3): a view that looks *through*
where a memory primitive lies says it is not there any more.

A primitive fused from earlier views and in the camera's field of view now is tested against
what this view saw: its points are projected into the image, and the surfaces the view's
primitives hold in each cell of a coarse grid (``cell`` pixels square) are compared with them.
Where every surface the view saw in a cell lies behind a point (by more than the depth noise
there and a registration margin), the ray passed through the point: it was seen through.
Where they lie in front, the point was hidden (no evidence); where they agree, the surface is
still there. A person's arm that moved away, or a veil of flying pixels between a foreground
and its background seen once, is seen through by the next views and goes.
"""

from __future__ import annotations

import numpy as np

from schemas import SceneObservation


def depth_sigma(z: np.ndarray | float) -> np.ndarray | float:
    """Axial σ of a structured-light depth reading at ``z`` m (Nguyen et al. 2012)."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


class ViewDepth:
    """The nearest surface the view's primitives hold in each ``cell``-pixel cell (inf: none)."""

    def __init__(self, obs: SceneObservation, cell: int) -> None:
        K = obs.intrinsics
        self.obs, self.cell = obs, cell
        self.shape = (-(-K.height // cell), -(-K.width // cell))
        self.near = np.full(self.shape, np.inf)
        points = [p.inliers for p in obs.primitives if len(p.inliers)]
        if points:
            r, c, z, ok = self.project(np.concatenate(points).astype(np.float64))
            np.minimum.at(self.near, (r[ok], c[ok]), z[ok])

    def project(self, points: np.ndarray):
        """(rows, cols, depth, inside image) of world points in this view's grid."""
        K, T = self.obs.intrinsics, np.asarray(self.obs.T_world_camera, float)
        cam = (points - T[:3, 3]) @ T[:3, :3]
        z = cam[:, 2]
        ok = z > 0.05
        zs = np.where(ok, z, 1.0)
        u = K.fx * cam[:, 0] / zs + K.cx
        v = K.fy * cam[:, 1] / zs + K.cy
        ok &= (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
        r = np.clip((v // self.cell).astype(np.int64), 0, self.shape[0] - 1)
        c = np.clip((u // self.cell).astype(np.int64), 0, self.shape[1] - 1)
        return r, c, z, ok

    def seen_through_each(
        self, groups: list[np.ndarray], margin: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """``seen_through`` of each group of points (all of them, in one projection)."""
        if not groups:
            return np.zeros(0, int), np.zeros(0, int)
        owner = np.repeat(np.arange(len(groups)), [len(g) for g in groups])
        r, c, z, ok = self.project(np.concatenate(groups).astype(np.float64, copy=False))
        near = np.where(ok, self.near[r, c], np.inf)
        tolerance = 3 * depth_sigma(z) + margin
        held = ok & np.isfinite(near)
        through = held & (near > z + tolerance)
        evidence = held & ~(near < z - tolerance)
        n = len(groups)
        return np.bincount(owner, through, n).astype(int), np.bincount(owner, evidence, n).astype(
            int
        )

    def seen_through(self, points: np.ndarray, margin: float, sample: int = 200) -> tuple[int, int]:
        """(points seen through, points with evidence either way) of a primitive's ``points``
        (at most ``sample`` of them, spread): seen through where the nearest surface in its
        cell lies more than 3 σ(z) + ``margin`` behind it; evidence where the cell holds any
        surface not hidden in front of it."""
        if len(points) > sample:
            points = points[np.linspace(0, len(points) - 1, sample).astype(int)]
        r, c, z, ok = self.project(np.asarray(points, np.float64))
        near = self.near[r[ok], c[ok]]
        z = z[ok]
        tolerance = 3 * depth_sigma(z) + margin
        held = np.isfinite(near)
        through = held & (near > z + tolerance)
        hidden = held & (near < z - tolerance)
        return int(through.sum()), int((held & ~hidden).sum())
