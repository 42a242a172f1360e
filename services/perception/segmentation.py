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
        cloud.radius if cloud.radius is not None else np.ones(cloud.shape, np.int32),
    )


@dataclass(frozen=True)
class ColourSplit:
    """When colour parts a region (see ``split_by_colour``)."""

    chroma: float = 0.08  # chromaticity step between neighbours that marks an edge ...
    dark: float = 25.0  # ... where both are brighter than this (r + g + b, 0-765)
    grey: float = 0.25  # saturation below which a colour is grey ...
    edge: float = 40.0  # ... and a step in brightness marks an edge (0-255 RGB) ...
    same_deg: float = 20.0  # ... between pixels whose normals differ by less than this
    part_min: int = 30  # a part is large from this many pixels ...
    part_share: float = 0.02  # ... and this share of its region
    rest_share: float = 0.2  # what no plain object covers is an object from this share
    distinct: float = 45.0  # mean colours of two objects differ by more than this
    parts_per_colour: int = 3  # an object's colour is in at most this many large parts
    object_size: float = 0.8  # m: only regions of objects (no larger) are split by colour


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
    labels 1..m (0 outside) and m. Only regions of the size of objects (``object_size``) are
    looked at: furniture is made of parts of several colours, which stay one piece.

    Parts are the connected pieces of a region between colour edges; large parts of one
    colour (within ``distinct``) form a group. A group in at most ``parts_per_colour`` parts
    is a plain object; a colour in many pieces interleaved with others is a pattern (a
    checker's cells). Each plain object becomes a region of its own, and what is left (a
    patterned object, or fine texture with no large part at all) one more when it is large
    enough; one object in all: no split. The pixels on colour edges join the nearest object
    of their region; every object's connected pieces become regions (tiny ones are dropped
    later, as any region under the minimum size)."""
    if n == 0 or not cloud.colours.any():
        return labels + 1, n
    edges = kernels.colour_edges(
        cloud.colours, cloud.normals, cloud.valid, float(np.cos(np.radians(config.same_deg))),
        config.edge, config.chroma, config.dark, config.grey,
    )  # fmt: skip
    parts, m = ndimage.label((labels >= 0) & ~edges)
    size, region, mean = kernels.part_stats(parts, labels, cloud.colours, m)
    region_size = np.bincount(labels[labels >= 0], minlength=n)
    big = (size >= config.part_min) & (size >= config.part_share * region_size[region])
    big[0] = False
    # the object each pixel seeds (-1: none, it joins the nearest one of its region); each
    # region worked on in its bounding box
    boxes = ndimage.find_objects(labels + 1, n)
    span = kernels.region_spans(cloud.points, labels, n)  # each region's largest side, m
    seeds = np.full(labels.shape, -1, np.int32)
    split = []
    next_object = 1
    for r in np.unique(region[big]):
        ids = np.flatnonzero(big & (region == r))
        rest_floor = max(config.part_min, config.rest_share * region_size[r])
        if len(ids) == 1 and region_size[r] - size[ids[0]] < rest_floor:
            continue  # one large part and little else: one object
        if span[r] > config.object_size:
            continue  # furniture: a counter's top and front are one piece, whatever colour
        box = _grown(boxes[r], labels.shape, 3)
        group = _colour_groups(mean[ids], config.distinct)
        plain = [g for g in range(group.max() + 1) if (group == g).sum() <= config.parts_per_colour]
        sub = parts[box]
        # each part's object (0: none) looked up per pixel, not np.isin's sort per object
        objects = np.zeros(m + 1, np.int32)
        for k, g in enumerate(plain):
            objects[ids[group == g]] = next_object + k
        own = objects[sub]
        plain_px = own > 0
        # the rest: the region away from the plain objects (not the edges between them)
        rest_px = (labels[box] == r) & ~ndimage.binary_dilation(plain_px, iterations=3)
        has_rest = rest_px.sum() >= rest_floor
        if len(plain) + has_rest < 2:
            continue  # one object
        split.append((r, box))
        sub_seeds = seeds[box]
        sub_seeds[plain_px] = own[plain_px]
        next_object += len(plain)
        if has_rest:
            sub_seeds[rest_px] = next_object
            next_object += 1
    if not split:
        return labels + 1, n
    out = labels + 1
    for r, box in split:  # the pixels between the seeds join the nearest, then the pieces
        inside = labels[box] == r
        grown = kernels.grow_labels(seeds[box], np.where(inside, r, -1).astype(np.int32))
        pieces, k = _pieces(grown, inside)
        out[box] = np.where(inside, np.where(pieces > 0, pieces + n, 0), out[box])
        n += k
    return out, n


def _grown(box: tuple[slice, slice], shape: tuple[int, int], by: int) -> tuple[slice, slice]:
    """A bounding box (slices) grown by ``by`` pixels, within the image."""
    return tuple(
        slice(max(0, b.start - by), min(size, b.stop + by))
        for b, size in zip(box, shape, strict=True)
    )


def _pieces(objects: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected pieces of each object label (4-connected, only within one label)."""
    out = np.zeros(objects.shape, np.int32)
    total = 0
    for obj in np.unique(objects[inside & (objects > 0)]):
        mask = inside & (objects == obj)
        lab, k = ndimage.label(mask)
        out[mask] = lab[mask] + total
        total += k
    return out, total


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
