"""Segmentation into disjoint regions (thesis A.6), LCCP-like, on the image grid.

Neighbouring pixels belong together unless the surface jumps between them (3D distance far
beyond the grid spacing) or they meet at a concave crease (normals differ by more than
``crease_deg`` and (n_i − n_j)·(p_i − p_j) < 0, the convexity criterion of LCCP). Convex
creases — the edges of a box — do not cut, so an object stays one region while it is cut off
the table it stands on. Regions are the connected components of what is left.

Depth and normals cannot part two objects whose faces are flush (a plank lying on two pillars,
a book on a crate of its footprint): there the colour image can. ``split_by_colour`` cuts a
region along colour edges between pixels of one surface orientation when that leaves two or
more large parts of clearly different colours that cover most of it; a texture, whose edges
leave only small pieces, is left whole.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from services.perception import kernels
from services.perception.cloud import OrganizedCloud


def boundaries(
    cloud: OrganizedCloud,
    *,
    jump_factor: float = 6.0,
    jump_abs: float = 0.01,
    crease_deg: float = 30.0,
    offset: int = 2,
) -> np.ndarray:
    """(h, w) bool: pixels on a depth jump (its far side) or a concave crease."""
    return kernels.boundaries(
        cloud.points,
        cloud.normals,
        cloud.valid,
        cloud.spacing,
        jump_factor,
        jump_abs,
        float(np.cos(np.radians(crease_deg))),
        offset,
    )


@dataclass(frozen=True)
class ColourSplit:
    """When colour parts a region (see ``split_by_colour``)."""

    chroma: float = 0.08  # chromaticity step between neighbours that marks an edge ...
    dark: float = 60.0  # ... where both are brighter than this (r + g + b, 0-765)
    edge: float = 40.0  # colour step that marks an edge (0-255 RGB) ...
    same_deg: float = 20.0  # ... between pixels whose normals differ by less than this
    part_min: int = 30  # a part is large from this many pixels ...
    part_share: float = 0.05  # ... and this share of its region
    cover: float = 0.6  # the large parts cover this share of the region
    distinct: float = 45.0  # mean colours of two objects differ by more than this


def _ordered(labels: np.ndarray, n: int, min_size: int) -> tuple[np.ndarray, int]:
    """Labels 0.. by size, largest first; regions under ``min_size`` pixels dropped (-1).
    ``labels``: 1..n, 0 outside."""
    if n == 0:
        return np.full(labels.shape, -1, np.int32), 0
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    sizes[0] = 0
    order = np.argsort(-sizes, kind="stable")
    keep = order[sizes[order] >= min_size]
    remap = np.full(n + 1, -1, np.int32)
    remap[keep] = np.arange(len(keep), dtype=np.int32)
    return remap[labels], len(keep)


def split_by_colour(
    cloud: OrganizedCloud, labels: np.ndarray, n: int, config: ColourSplit = ColourSplit()
) -> tuple[np.ndarray, int]:
    """Regions (labels 0..n-1, -1 outside) cut where colour tells objects apart; returns
    labels 1..m (0 outside) and m. Parts: connected pieces of a region between colour edges;
    a region is split when its large parts cover ``cover`` of it and not all have one colour.
    Large parts of one colour (within ``distinct``) stay together; the pixels between parts
    join the nearest part of their region."""
    if n == 0 or not cloud.colours.any():
        return labels + 1, n
    edges = kernels.colour_edges(
        cloud.colours, cloud.normals, cloud.valid,
        float(np.cos(np.radians(config.same_deg))), config.edge, config.chroma, config.dark,
    )  # fmt: skip
    parts, m = ndimage.label((labels >= 0) & ~edges)
    flat = parts.ravel()
    size = np.bincount(flat, minlength=m + 1)
    size[0] = 0
    region = np.full(m + 1, -1)
    region[flat] = labels.ravel()
    region_size = np.bincount(labels[labels >= 0], minlength=n)
    big = (size >= config.part_min) & (size >= config.part_share * region_size[region])
    big[0] = False
    colours = cloud.colours.reshape(-1, 3).astype(np.float64)
    mean = (
        np.stack([np.bincount(flat, colours[:, k], minlength=m + 1) for k in range(3)], 1)
        / np.maximum(size, 1)[:, None]
    )
    out = labels + 1
    next_label = n + 1
    seeds = np.full(labels.shape, -1, np.int32)
    split = np.zeros(n, bool)
    for r in np.unique(region[big]):
        ids = np.flatnonzero(big & (region == r))
        if len(ids) < 2 or size[ids].sum() < config.cover * region_size[r]:
            continue
        group = _colour_groups(mean[ids], config.distinct)
        if group.max() == 0:
            continue  # one colour: one object
        split[r] = True
        for g in range(group.max() + 1):
            seeds[np.isin(parts, ids[group == g])] = r + 1 if g == 0 else next_label
            next_label += g > 0
    if not split.any():
        return out, n
    inside = split[np.maximum(labels, 0)] & (labels >= 0)
    grown = kernels.grow_labels(np.where(inside, seeds, np.where(labels >= 0, -2, -1)), labels)
    out = np.where(inside, np.maximum(grown, 0), out)
    return out, next_label - 1


def _colour_groups(colours: np.ndarray, distinct: float) -> np.ndarray:
    """Group index per colour: colours closer than ``distinct`` (single linkage) share one."""
    group = np.arange(len(colours))
    d = np.linalg.norm(colours[:, None] - colours[None], axis=2)
    for i, j in zip(*np.nonzero(np.triu(d < distinct, 1)), strict=True):
        group[group == group[j]] = group[i]
    _, group = np.unique(group, return_inverse=True)
    return group


def segment(
    cloud: OrganizedCloud, min_size: int = 30, colour: ColourSplit | None = ColourSplit(), **kwargs
) -> tuple[np.ndarray, int]:
    """Labels (h, w) int32, -1 outside every region, and the number of regions (each at least
    ``min_size`` pixels), largest first. ``colour``: how the colour image splits regions
    (None: geometry only)."""
    inside = cloud.valid & ~boundaries(cloud, **kwargs)
    labels, n = ndimage.label(inside)
    if colour is not None and n:
        labels, n = _ordered(labels, n, 1)
        labels, n = split_by_colour(cloud, labels, n, colour)
    return _ordered(labels, n, min_size)
