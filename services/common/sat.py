"""The separating-axis test of two oriented boxes (15 axes: 3 + 3 face normals, 9 edge
crosses), shared by perception (spatial relations of one view) and the scene memory (the
fused model's spatial edges, Algorithm 2's overlap checks): numba kernels on plain arrays, one
pair or every pair of a set at once."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def overlap(A, ca, ha, B, cb, hb) -> bool:
    """No axis separates the boxes (rotations A, B with the boxes' axes as columns, centres
    ca, cb, half extents ha, hb); near-zero edge crosses (parallel edges) are skipped."""
    dx, dy, dz = cb[0] - ca[0], cb[1] - ca[1], cb[2] - ca[2]
    for k in range(15):
        if k < 3:
            x, y, z = A[0, k], A[1, k], A[2, k]
        elif k < 6:
            x, y, z = B[0, k - 3], B[1, k - 3], B[2, k - 3]
        else:
            i, j = (k - 6) // 3, (k - 6) % 3
            x = A[1, i] * B[2, j] - A[2, i] * B[1, j]
            y = A[2, i] * B[0, j] - A[0, i] * B[2, j]
            z = A[0, i] * B[1, j] - A[1, i] * B[0, j]
        n = np.sqrt(x * x + y * y + z * z)
        if n <= 1e-9:
            continue
        ra = rb = 0.0
        for i in range(3):
            ra += abs(x * A[0, i] + y * A[1, i] + z * A[2, i]) * ha[i]
            rb += abs(x * B[0, i] + y * B[1, i] + z * B[2, i]) * hb[i]
        if abs(x * dx + y * dy + z * dz) > ra + rb:  # all scaled by n alike
            return False
    return True


@njit(cache=True, nogil=True)
def overlap_pairs(rotations, centres, halves):
    """(n, n) bool: ``overlap`` of every pair of the n boxes (symmetric, True on the
    diagonal)."""
    n = centres.shape[0]
    out = np.ones((n, n), np.bool_)
    for a in range(n):
        for b in range(a + 1, n):
            hit = overlap(rotations[a], centres[a], halves[a], rotations[b], centres[b], halves[b])
            out[a, b] = out[b, a] = hit
    return out


def boxes_overlap(
    A: np.ndarray, ca: np.ndarray, extent_a: np.ndarray,
    B: np.ndarray, cb: np.ndarray, extent_b: np.ndarray, epsilon: float = 0.0,
) -> bool:  # fmt: skip
    """Do two boxes (rotation, centre, full extents), each grown by ``epsilon`` on every
    side, overlap?"""
    # copies: one writable C type, or numba compiles anew for a read-only (decoded) array
    hit = overlap(
        np.array(A, np.float64, order="C"), np.array(ca, np.float64),
        np.asarray(extent_a, np.float64) / 2 + epsilon,
        np.array(B, np.float64, order="C"), np.array(cb, np.float64),
        np.asarray(extent_b, np.float64) / 2 + epsilon,
    )  # fmt: skip
    return bool(hit)


def pairs_overlap(
    rotations: np.ndarray, centres: np.ndarray, extents: np.ndarray, epsilon: float = 0.0
) -> np.ndarray:
    """``overlap_pairs`` of boxes given as (n, 3, 3) rotations, (n, 3) centres and full
    extents, each grown by ``epsilon``."""
    n = len(centres)
    return overlap_pairs(
        np.array(np.reshape(rotations, (n, 3, 3)), np.float64, order="C"),
        np.array(np.reshape(centres, (n, 3)), np.float64, order="C"),
        np.asarray(np.reshape(extents, (n, 3)), np.float64) / 2 + epsilon,
    )


def warm_up() -> None:
    """Load (or, on a machine's first run, compile) both kernels before the first real boxes."""
    R, c, e = np.eye(3), np.zeros(3), np.ones(3)
    boxes_overlap(R, c, e, R, c + 0.5, e)
    pairs_overlap(np.stack([R, R]), np.stack([c, c + 0.5]), np.stack([e, e]))
