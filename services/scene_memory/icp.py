"""Compiled point-to-plane ICP against a ``VoxelMap`` (numba), the kernels of
``registration``.

A point is matched to the mean of its own voxel, or, where that is empty, to the nearest mean
of the neighbours around its nearest corner; the match's plane has the normal of the points of
the 3×3×3 voxels around it and passes through the voxel's mean (fitted when first matched,
refitted as the voxel grows). Each Gauss-Newton step linearises
r = n·(Rq + t) + d about the current pose, J = [(q × n)ᵀ nᵀ], with Tukey's biweight on r, and
solves it for the unknowns ``free`` names (all six, or a ground platform's x, y and yaw: ``FULL``,
``PLANAR``; the rotation is about the world's origin, so yaw and a shift span SE(2)). A
hash lookup where a point enters a new cell (against a persistent map, so nothing is rebuilt
per frame) replaces Open3D's k-d tree build, normal estimation and nearest-neighbour search,
which cost a kitchen frame 300-400 ms against a 20-view map.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from services.scene_memory.voxel_map import find

#: a voxel's plane is refitted once its count has grown by this factor since the last fit
REFIT = 1.5
#: ``_behind``: |cos| of the angle between a surface's normal and the direction it was seen
#: along (or the camera's direction now) below which its side is not judged (about 78°)
FACING = 0.2
#: the unknowns ``icp`` solves for, of the step (ωx, ωy, ωz, tx, ty, tz) (world frame): all
#: six, or the platform's shift in the ground plane and its yaw about the world's vertical
FULL = np.arange(6, dtype=np.int64)
PLANAR = np.array([2, 3, 4], dtype=np.int64)


@njit(cache=True, nogil=True, inline="always")
def _cross_norm(a0, a1, a2, b0, b1, b2) -> tuple[float, float, float, float]:
    """a × b and its squared length."""
    v0, v1, v2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    return v0, v1, v2, v0 * v0 + v1 * v1 + v2 * v2


@njit(cache=True, nogil=True)
def smallest_eigen(
    xx: float, xy: float, xz: float, yy: float, yz: float, zz: float
) -> tuple[float, float, float, float]:
    """The smallest eigenvalue of the symmetric 3×3 matrix [[xx xy xz] [xy yy yz] [xz yz zz]]
    and its unit eigenvector, (λ, x, y, z), in closed form without allocating: the eigenvalue
    by the trigonometric solution of the characteristic cubic, the vector as the longest cross
    product of two rows of a − λI."""
    p1 = xy * xy + xz * xz + yz * yz
    q = (xx + yy + zz) / 3.0
    p2 = (xx - q) ** 2 + (yy - q) ** 2 + (zz - q) ** 2 + 2.0 * p1
    if p2 <= 1e-30:
        return q, 0.0, 0.0, 1.0  # isotropic: any direction
    p = math.sqrt(p2 / 6.0)
    b00, b11, b22 = (xx - q) / p, (yy - q) / p, (zz - q) / p
    b01, b02, b12 = xy / p, xz / p, yz / p
    det = (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02)
           + b02 * (b01 * b12 - b11 * b02))  # fmt: skip
    phi = math.acos(min(1.0, max(-1.0, det / 2.0))) / 3.0
    lam = q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)  # the smallest root
    a00, a11, a22 = xx - lam, yy - lam, zz - lam
    v0, v1, v2, best = _cross_norm(a00, xy, xz, xy, a11, yz)
    w0, w1, w2, n = _cross_norm(a00, xy, xz, xz, yz, a22)
    if n > best:
        v0, v1, v2, best = w0, w1, w2, n
    w0, w1, w2, n = _cross_norm(xy, a11, yz, xz, yz, a22)
    if n > best:
        v0, v1, v2, best = w0, w1, w2, n
    if best <= 0:
        return lam, 0.0, 0.0, 1.0
    k = 1.0 / math.sqrt(best)
    return lam, v0 * k, v1 * k, v2 * k


@njit(cache=True, nogil=True)
def _normal(
    table: np.ndarray, index: np.ndarray, stats: np.ndarray,
    voxel: float, s: int, planes: np.ndarray, fitted: np.ndarray, thickness: float,
) -> bool:  # fmt: skip
    """Whether voxel ``s`` has a plane (n, d; n·x + d = 0): the least-squares plane of the
    points of the 3×3×3 voxels around it (at least 6 of them, their RMS distance to it at most
    ``thickness``: around an edge or a corner the points are no plane, and a plane through
    them pulls the frame off its true pose), cached in ``planes`` and refitted when the
    voxel's count has grown by ``REFIT`` since (``fitted``: the count at the fit, negative
    when it failed)."""
    last = fitted[s]
    if last != 0 and stats[s, 0] < REFIT * abs(last):
        return last > 0
    ox, oy, oz = index[s, 0], index[s, 1], index[s, 2]
    n = sx = sy = sz = sxx = sxy = sxz = syy = syz = szz = 0.0
    for dx in range(-1, 2):
        for dy in range(-1, 2):
            for dz in range(-1, 2):
                j = find(table, ox + dx, oy + dy, oz + dz)
                if j < 0:
                    continue
                # move the neighbour's sums to voxel s's corner: p' = p + d·voxel
                m = stats[j, 0]
                jx, jy, jz = stats[j, 1], stats[j, 2], stats[j, 3]
                ex, ey, ez = dx * voxel, dy * voxel, dz * voxel
                n += m
                sx += jx + m * ex
                sy += jy + m * ey
                sz += jz + m * ez
                sxx += stats[j, 4] + 2 * ex * jx + m * ex * ex
                sxy += stats[j, 5] + ex * jy + ey * jx + m * ex * ey
                sxz += stats[j, 6] + ex * jz + ez * jx + m * ex * ez
                syy += stats[j, 7] + 2 * ey * jy + m * ey * ey
                syz += stats[j, 8] + ey * jz + ez * jy + m * ey * ez
                szz += stats[j, 9] + 2 * ez * jz + m * ez * ez
    if n < 6:
        fitted[s] = -stats[s, 0]
        return False
    mx, my, mz = sx / n, sy / n, sz / n
    spread, nx, ny, nz = smallest_eigen(
        sxx / n - mx * mx, sxy / n - mx * my, sxz / n - mx * mz,
        syy / n - my * my, syz / n - my * mz, szz / n - mz * mz,
    )  # fmt: skip
    if spread > thickness * thickness:
        fitted[s] = -stats[s, 0]
        return False
    own = stats[s, 0]
    planes[s, 0], planes[s, 1], planes[s, 2] = nx, ny, nz
    planes[s, 3] = -(nx * (ox * voxel + stats[s, 1] / own) + ny * (oy * voxel + stats[s, 2] / own)
                     + nz * (oz * voxel + stats[s, 3] / own))  # fmt: skip
    fitted[s] = stats[s, 0]
    return True


@njit(cache=True, nogil=True)
def candidates(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """An empty cache of ``n`` points' matches against one ``VoxelMap`` (``_match``, which
    fills it): per point its cell and octant (ix, iy, iz, octant), the rows of its candidate
    voxels (its own, or where that is empty the seven others around its nearest corner; -1:
    none) and their means, and the row and plane of its last match. ``icp`` and ``residuals``
    share it for the same points and map."""
    cell = np.full((n, 4), np.iinfo(np.int64).min, np.int64)
    rows = np.full((n, 9), -1, np.int64)  # the eight candidates, then the last match
    means = np.empty((n, 8, 3))
    plane = np.empty((n, 4))
    return cell, rows, means, plane


@njit(cache=True, nogil=True)
def _match(
    table: np.ndarray, stats: np.ndarray, voxel: float,
    x: float, y: float, z: float,
    i: int, cell: np.ndarray, rows: np.ndarray, means: np.ndarray,
) -> tuple[int, float, float, float]:  # fmt: skip
    """The voxel a world point is matched to: its own, else, of the seven neighbours that
    share the corner nearest to the point (which hold every map point within half a voxel of
    it), the one with the nearest mean; (row, mean) or (-1, …). The candidates are looked up
    in the map's hash only when point ``i`` has left the cell or octant it was in at its last
    match (``candidates``): near convergence no point does, and the lookups, a cache miss
    each, were most of an ICP step's time."""
    inv = 1.0 / voxel
    fx, fy, fz = x * inv, y * inv, z * inv
    ix, iy, iz = math.floor(fx), math.floor(fy), math.floor(fz)
    sx = 1 if fx - ix >= 0.5 else -1
    sy = 1 if fy - iy >= 0.5 else -1
    sz = 1 if fz - iz >= 0.5 else -1
    octant = (sx + 1) + 3 * (sy + 1) + 9 * (sz + 1)
    if cell[i, 0] != ix or cell[i, 1] != iy or cell[i, 2] != iz or cell[i, 3] != octant:
        cell[i, 0], cell[i, 1], cell[i, 2], cell[i, 3] = ix, iy, iz, octant
        own = find(table, ix, iy, iz)
        rows[i, 0] = own
        if own >= 0:
            n = stats[own, 0]
            means[i, 0, 0] = ix * voxel + stats[own, 1] / n
            means[i, 0, 1] = iy * voxel + stats[own, 2] / n
            means[i, 0, 2] = iz * voxel + stats[own, 3] / n
            rows[i, 1:8] = -1
        for corner in range(1 if own < 0 else 8, 8):
            jx = ix + sx * (corner & 1)
            jy = iy + sy * ((corner >> 1) & 1)
            jz = iz + sz * (corner >> 2)
            j = find(table, jx, jy, jz)
            rows[i, corner] = j
            if j >= 0:
                n = stats[j, 0]
                means[i, corner, 0] = jx * voxel + stats[j, 1] / n
                means[i, corner, 1] = jy * voxel + stats[j, 2] / n
                means[i, corner, 2] = jz * voxel + stats[j, 3] / n
    best, bx, by, bz, bd = -1, 0.0, 0.0, 0.0, 1e30
    for corner in range(8):
        j = rows[i, corner]
        if j < 0:
            continue
        mx, my, mz = means[i, corner, 0], means[i, corner, 1], means[i, corner, 2]
        d = (mx - x) ** 2 + (my - y) ** 2 + (mz - z) ** 2
        if d < bd:
            best, bx, by, bz, bd = j, mx, my, mz, d
    return best, bx, by, bz


@njit(cache=True, nogil=True, inline="always")
def _plane(
    table: np.ndarray, index: np.ndarray, stats: np.ndarray, voxel: float,
    s: int, planes: np.ndarray, fitted: np.ndarray, thickness: float, i: int, rows: np.ndarray,
    plane: np.ndarray,
) -> bool:  # fmt: skip
    """Whether voxel ``s`` has a plane (``_normal``), copied to ``plane[i]``; reused without
    touching the map while point ``i`` keeps its match (the map does not change during one
    registration, so neither does the plane)."""
    if rows[i, 8] == s:
        return True
    if not _normal(table, index, stats, voxel, s, planes, fitted, thickness):
        return False
    rows[i, 8] = s
    plane[i] = planes[s]
    return True


@njit(cache=True, nogil=True, inline="always")
def _moved(T: np.ndarray, p: np.ndarray, i: int) -> tuple[float, float, float]:
    """Point ``p[i]`` moved by the rigid transform ``T``."""
    x, y, z = p[i, 0], p[i, 1], p[i, 2]
    return (T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3],
            T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3],
            T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3])  # fmt: skip


@njit(cache=True, nogil=True, inline="always")
def _behind(
    stats: np.ndarray, s: int, nx: float, ny: float, nz: float,
    x: float, y: float, z: float, eye: np.ndarray,
) -> bool:  # fmt: skip
    """Whether a camera at ``eye`` looks at voxel ``s``'s surface (normal n, through the point
    x, y, z) from behind, as it was seen so far (its points' directions to their cameras,
    Σv): the far face of a thin body seen for the first time, which must not be matched to
    its near face a few centimetres away (a frame from behind a 10 cm box slid 6 cm onto it).
    Only where the surface's side is clear (Σv, normalised, at least ``FACING`` off its
    plane) and the camera is clearly on the other (the same margin): a grazing view decides
    nothing. ``eye`` NaN: no check."""
    vx, vy, vz = stats[s, 10], stats[s, 11], stats[s, 12]
    seen = nx * vx + ny * vy + nz * vz
    length = math.sqrt(vx * vx + vy * vy + vz * vz)
    if not (length > 0.0) or abs(seen) < FACING * length or math.isnan(eye[0]):
        return False
    ex, ey, ez = eye[0] - x, eye[1] - y, eye[2] - z
    now = nx * ex + ny * ey + nz * ez
    distance = math.sqrt(ex * ex + ey * ey + ez * ez)
    return (now > 0.0) != (seen > 0.0) and abs(now) > FACING * distance


@njit(cache=True, nogil=True, inline="always")
def _residual(
    source: np.ndarray, i: int, T: np.ndarray, table: np.ndarray, index: np.ndarray,
    stats: np.ndarray, voxel: float, planes: np.ndarray, fitted: np.ndarray, thickness: float,
    d2: float, cache: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], eye: np.ndarray,
) -> tuple[bool, float, float, float, float, float, float, float]:  # fmt: skip
    """Point ``source[i]`` moved by ``T`` against the map: whether it has a match within
    √``d2`` that has a plane facing the camera at ``eye`` (moved by ``T`` already; ``_behind``),
    its point-to-plane residual, the plane's normal and the moved point."""
    cell, rows, means, plane = cache
    x, y, z = _moved(T, source, i)
    s, mx, my, mz = _match(table, stats, voxel, x, y, z, i, cell, rows, means)
    if s < 0 or (mx - x) ** 2 + (my - y) ** 2 + (mz - z) ** 2 > d2:
        return False, 0.0, 0.0, 0.0, 0.0, x, y, z
    if not _plane(table, index, stats, voxel, s, planes, fitted, thickness, i, rows, plane):
        return False, 0.0, 0.0, 0.0, 0.0, x, y, z
    nx, ny, nz = plane[i, 0], plane[i, 1], plane[i, 2]
    if _behind(stats, s, nx, ny, nz, x, y, z, eye):
        return False, 0.0, 0.0, 0.0, 0.0, x, y, z
    return True, nx * x + ny * y + nz * z + plane[i, 3], nx, ny, nz, x, y, z


@njit(cache=True, nogil=True, inline="always")
def _moved_eye(T: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """The camera position ``eye`` (3,) moved by ``T`` (NaN stays NaN: no check)."""
    out = np.empty(3)
    for a in range(3):
        out[a] = T[a, 0] * eye[0] + T[a, 1] * eye[1] + T[a, 2] * eye[2] + T[a, 3]
    return out


@njit(cache=True, nogil=True)
def _exp(w: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The rigid transform of a step (rotation vector ``w``, translation ``t``), 4×4."""
    T = np.eye(4)
    a = math.sqrt(w @ w)
    if a > 1e-12:
        k = w / a
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        T[:3, :3] = np.eye(3) + math.sin(a) * K + (1.0 - math.cos(a)) * (K @ K)
    T[:3, 3] = t
    return T


@njit(cache=True, nogil=True)
def icp(
    source: np.ndarray, table: np.ndarray, index: np.ndarray,
    stats: np.ndarray, voxel: float, planes: np.ndarray, fitted: np.ndarray,
    thickness: float, T0: np.ndarray, max_distance: float, kernel: float, iterations: int,
    tolerance: float, weights: np.ndarray,
    cache: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], free: np.ndarray,
    eye: np.ndarray,
) -> tuple[np.ndarray, int]:  # fmt: skip
    """Point-to-plane Gauss-Newton with Tukey's biweight (k = ``kernel``) from ``T0``: the
    transform (world → world) that puts ``source`` (n, 3) on the map, and the steps taken.
    Each step solves for the unknowns ``free`` (``FULL``, ``PLANAR``), the others stay 0.
    A match farther than ``max_distance`` from its voxel's mean is dropped; the loop stops
    when a step moves less than ``tolerance`` (m, or rad × 1 m). ``eye``: the camera's
    position (world, as ``source``; NaN: unknown), for ``_behind``."""
    T = T0.copy()
    k2 = kernel * kernel
    d2 = max_distance * max_distance
    steps = 0
    for _ in range(iterations):
        steps += 1
        H = np.zeros((6, 6))
        g = np.zeros(6)
        J = np.empty(6)
        at = _moved_eye(T, eye)
        for i in range(source.shape[0]):
            ok, r, nx, ny, nz, x, y, z = _residual(
                source, i, T, table, index, stats, voxel, planes, fitted, thickness, d2, cache, at
            )
            if not ok or r * r >= k2:
                continue
            u = 1.0 - r * r / k2
            w = u * u * weights[i]
            J[0], J[1], J[2] = y * nz - z * ny, z * nx - x * nz, x * ny - y * nx
            J[3], J[4], J[5] = nx, ny, nz
            for a in range(6):
                g[a] += w * J[a] * r
                for b in range(a, 6):
                    H[a, b] += w * J[a] * J[b]
        m = free.shape[0]
        Hf = np.empty((m, m))
        gf = np.empty(m)
        trace = 0.0
        for a in range(m):
            gf[a] = g[free[a]]
            trace += H[free[a], free[a]]
            for b in range(m):
                i, j = min(free[a], free[b]), max(free[a], free[b])
                Hf[a, b] = H[i, j]
        if trace <= 0:
            break
        step = -np.linalg.solve(Hf + 1e-9 * np.eye(m), gf)
        x = np.zeros(6)
        for a in range(m):
            x[free[a]] = step[a]
        T = _exp(x[:3], x[3:]) @ T
        if math.sqrt(x @ x) < tolerance:
            break
    return T, steps


@njit(cache=True, nogil=True)
def residuals(
    source: np.ndarray, table: np.ndarray, index: np.ndarray,
    stats: np.ndarray, voxel: float, planes: np.ndarray, fitted: np.ndarray,
    thickness: float, T: np.ndarray, max_distance: float,
    cache: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray], eye: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Where ``source`` moved by ``T`` meets the map: per point whether it is matched within
    ``max_distance`` (by a surface that faces the camera at ``eye``, as ``icp``), its
    point-to-plane residual and the match's normal."""
    n = source.shape[0]
    matched = np.zeros(n, np.bool_)
    r = np.zeros(n)
    nrm = np.zeros((n, 3))
    d2 = max_distance * max_distance
    at = _moved_eye(T, eye)
    for i in range(n):
        ok, ri, nx, ny, nz, _, _, _ = _residual(
            source, i, T, table, index, stats, voxel, planes, fitted, thickness, d2, cache, at
        )
        if ok:
            matched[i] = True
            r[i] = ri
            nrm[i, 0], nrm[i, 1], nrm[i, 2] = nx, ny, nz
    return matched, r, nrm
