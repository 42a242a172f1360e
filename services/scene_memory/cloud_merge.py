"""The registered cloud's merge of a frame: one point per voxel of ``cloud_voxel`` (a voxel's
first point stays), the oldest dropped beyond the cap, in one compiled call that lets the GIL
go once (``SceneMemory._add_to_cloud``).

Only the frame's points are sorted; they are looked up in the cloud's sorted voxel keys by one
merge walk, and the keys of the points kept and dropped merged in and out the same way. As a
dozen numpy calls the merge took 10 ms of a kitchen frame alone and 22-32 ms in the live stack:
each call that let the GIL go waited up to a switch interval (5 ms) to take it back from the
node's other threads (257 ms with one busy Python thread beside it; 1 call: ``benchmarks/``
``cloud_merge.py``)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def voxel_keys(pts, voxel):
    """``fusion.voxel_keys`` of float32 points, to the bit: the division in float32, as numpy
    divides a float32 array by a Python float."""
    v = np.float32(voxel)
    keys = np.empty(pts.shape[0], np.int64)
    for r in range(pts.shape[0]):
        kx = math.floor(np.float32(pts[r, 0]) / v) + (1 << 20)
        ky = math.floor(np.float32(pts[r, 1]) / v) + (1 << 20)
        kz = math.floor(np.float32(pts[r, 2]) / v) + (1 << 20)
        keys[r] = (kx << 42) | (ky << 21) | kz
    return keys


@njit(cache=True, nogil=True)
def add_frame(cloud, colours, viewpoints, cloud_keys, index, pts, rgb, eye, voxel, cap):
    """The cloud (float32 points, colours, viewpoints, voxel keys point by point, and those
    keys sorted: ``index``) with the frame's float32 points ``pts`` (colours ``rgb``, seen from
    ``eye``) added where their voxel holds no point yet, each new voxel's first point in frame
    order, and the oldest points dropped beyond ``cap``. Returns the five arrays anew (the old
    ones are not written)."""
    keys = voxel_keys(pts, voxel)
    order = np.argsort(keys)
    n = keys.shape[0]
    # the frame's voxels in key order, each one's first point, unless the cloud has the voxel
    new = np.zeros(n, np.bool_)
    added_keys = np.empty(n, np.int64)
    added = 0
    i = j = 0
    while j < n:
        k, first = keys[order[j]], order[j]
        j += 1
        while j < n and keys[order[j]] == k:  # the sort is not stable: the run's least index
            first = min(first, order[j])
            j += 1
        while i < index.shape[0] and index[i] < k:
            i += 1
        if i < index.shape[0] and index[i] == k:
            continue
        new[first] = True
        added_keys[added] = k
        added += 1
    old = cloud_keys.shape[0]
    drop = max(0, old + added - cap)
    size = old + added - drop
    out = np.empty((size, 3), np.float32)
    out_colours = np.empty((size, 3), np.uint8)
    out_viewpoints = np.empty((size, 3), np.float32)
    out_keys = np.empty(size, np.int64)
    kept = max(0, old - drop)
    out[:kept], out_colours[:kept] = cloud[old - kept :], colours[old - kept :]
    out_viewpoints[:kept], out_keys[:kept] = viewpoints[old - kept :], cloud_keys[old - kept :]
    # the frame's new points; > 0: the frame alone is past the cap, its first new points go too
    skip = drop - old
    gone = np.empty(drop, np.int64)
    gone[: drop - max(skip, 0)] = cloud_keys[: drop - max(skip, 0)]
    at = kept
    for r in range(n):
        if new[r]:
            if skip > 0:
                gone[drop - skip] = keys[r]
                skip -= 1
                continue
            for c in range(3):
                out[at, c], out_colours[at, c], out_viewpoints[at, c] = pts[r, c], rgb[r, c], eye[c]
            out_keys[at] = keys[r]
            at += 1
    # the sorted keys: the cloud's and the added ones merged, the dropped ones left out
    gone.sort()
    out_index = np.empty(size, np.int64)
    a = b = g = m = 0
    while a < index.shape[0] or b < added:
        if b == added or (a < index.shape[0] and index[a] < added_keys[b]):
            k = index[a]
            a += 1
        else:
            k = added_keys[b]
            b += 1
        while g < drop and gone[g] < k:
            g += 1
        if g < drop and gone[g] == k:
            continue
        out_index[m] = k
        m += 1
    return out, out_colours, out_viewpoints, out_keys, out_index


def warm_up() -> None:
    """Merge a made-up frame once: loads the compiled merge, or compiles it on a machine's
    first run, before the first real frame rather than with it."""
    empty = np.zeros((0, 3), np.float32)
    keys = np.zeros(0, np.int64)
    pts = np.arange(12, dtype=np.float32).reshape(4, 3) * 0.01
    add_frame(empty, np.zeros((0, 3), np.uint8), empty, keys, keys, pts,
              np.zeros((4, 3), np.uint8), np.zeros(3, np.float32), 0.01, 3)  # fmt: skip
