"""Compiled per-pixel kernels of the organized cloud (numba): normals from box-filtered points
and the segmentation boundaries. One pass over the grid each, instead of a dozen numpy passes."""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def normals(
    points: np.ndarray, valid: np.ndarray, radius: np.ndarray, centre: np.ndarray
) -> np.ndarray:
    """Unit normals (h, w, 3), facing ``centre``, as the cross product of the tangents of the
    points averaged over (2·k + 1)² windows, k = ``radius`` (h, w) of the pixel (box sums from
    integral images: any window costs the same); 0 where unknown."""
    h, w = valid.shape
    S = np.zeros((h + 1, w + 1, 3), np.float64)
    C = np.zeros((h + 1, w + 1), np.int64)
    for r in range(h):
        for c in range(w):
            v = valid[r, c]
            for j in range(3):
                S[r + 1, c + 1, j] = (
                    S[r, c + 1, j] + S[r + 1, c, j] - S[r, c, j] + (points[r, c, j] if v else 0.0)
                )
            C[r + 1, c + 1] = C[r, c + 1] + C[r + 1, c] - C[r, c] + (1 if v else 0)
    mean = np.zeros((h, w, 3), np.float32)
    have = np.zeros((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            k = radius[r, c]
            r0, r1 = max(0, r - k), min(h, r + k + 1)
            c0, c1 = max(0, c - k), min(w, c + k + 1)
            n = C[r1, c1] - C[r0, c1] - C[r1, c0] + C[r0, c0]
            for j in range(3):
                mean[r, c, j] = (S[r1, c1, j] - S[r0, c1, j] - S[r1, c0, j] + S[r0, c0, j]) / n
            have[r, c] = True
    out = np.zeros((h, w, 3), np.float32)
    for r in range(h):
        for c in range(w):
            k = max(1, radius[r, c])
            if r < k or r >= h - k or c < k or c >= w - k:
                continue
            if not (
                have[r, c]
                and have[r, c - k]
                and have[r, c + k]
                and have[r - k, c]
                and have[r + k, c]
            ):
                continue
            ux = mean[r, c + k, 0] - mean[r, c - k, 0]
            uy = mean[r, c + k, 1] - mean[r, c - k, 1]
            uz = mean[r, c + k, 2] - mean[r, c - k, 2]
            vx = mean[r + k, c, 0] - mean[r - k, c, 0]
            vy = mean[r + k, c, 1] - mean[r - k, c, 1]
            vz = mean[r + k, c, 2] - mean[r - k, c, 2]
            nx = uy * vz - uz * vy
            ny = uz * vx - ux * vz
            nz = ux * vy - uy * vx
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm <= 0:
                continue
            if (
                nx * (centre[0] - points[r, c, 0])
                + ny * (centre[1] - points[r, c, 1])
                + nz * (centre[2] - points[r, c, 2])
                < 0
            ):
                norm = -norm
            out[r, c, 0] = nx / norm
            out[r, c, 1] = ny / norm
            out[r, c, 2] = nz / norm
    return out


@njit(cache=True, nogil=True)
def boundaries(
    points: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    spacing: np.ndarray,
    jump_factor: float,
    jump_abs: float,
    cos_crease: float,
    offset: int,
    radius: np.ndarray,
) -> np.ndarray:
    """(h, w) bool: the far side of depth jumps between neighbours, and the middle of concave
    creases between pixels ``offset`` · k apart, k = the pixel's smoothing ``radius`` (its
    normals are averaged over that much: a crease is judged beyond it) (LCCP convexity:
    (n_i − n_j)·(p_i − p_j) < 0)."""
    h, w = valid.shape
    edge = np.zeros((h, w), np.bool_)
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            step = offset * max(1, radius[r, c])
            half = step // 2
            for dr, dc in ((0, 1), (1, 0)):
                r2, c2 = r + dr, c + dc
                if r2 < h and c2 < w and valid[r2, c2]:
                    dx = points[r, c, 0] - points[r2, c2, 0]
                    dy = points[r, c, 1] - points[r2, c2, 1]
                    dz = points[r, c, 2] - points[r2, c2, 2]
                    limit = jump_factor * min(spacing[r, c], spacing[r2, c2]) + jump_abs
                    if dx * dx + dy * dy + dz * dz > limit * limit:
                        if spacing[r, c] > spacing[r2, c2]:
                            edge[r, c] = True
                        else:
                            edge[r2, c2] = True
                r2, c2 = r + dr * step, c + dc * step
                if r2 >= h or c2 >= w or not valid[r2, c2]:
                    continue
                ax, ay, az = normals[r, c, 0], normals[r, c, 1], normals[r, c, 2]
                bx, by, bz = normals[r2, c2, 0], normals[r2, c2, 1], normals[r2, c2, 2]
                if (ax == 0 and ay == 0 and az == 0) or (bx == 0 and by == 0 and bz == 0):
                    continue
                if ax * bx + ay * by + az * bz >= cos_crease:
                    continue
                convexity = (
                    (ax - bx) * (points[r, c, 0] - points[r2, c2, 0])
                    + (ay - by) * (points[r, c, 1] - points[r2, c2, 1])
                    + (az - bz) * (points[r, c, 2] - points[r2, c2, 2])
                )
                if convexity < 0:
                    if step > 1:
                        edge[r + dr * half, c + dc * half] = True
                    else:
                        edge[r, c] = True
                        edge[r2, c2] = True
    return edge


@njit(cache=True, nogil=True)
def _plane_inliers(X, N, nx, ny, nz, d, dist, cos_min, out):
    count = 0
    for i in range(X.shape[0]):
        r = abs(X[i, 0] * nx + X[i, 1] * ny + X[i, 2] * nz + d)
        c = abs(N[i, 0] * nx + N[i, 1] * ny + N[i, 2] * nz)
        ok = r < dist and c > cos_min
        out[i] = ok
        count += ok
    return count


@njit(cache=True, nogil=True)
def _columns(X, subset):
    """(3, m): the ``subset`` rows of an (n, 3) array as contiguous columns (the hypotheses'
    scoring loops then run over them in SIMD instead of gathering each point per hypothesis)."""
    out = np.empty((3, subset.shape[0]))
    for k in range(subset.shape[0]):
        for a in range(3):
            out[a, k] = X[subset[k], a]
    return out


@njit(cache=True, nogil=True)
def plane_ransac(X, N, triples, subset, dist, cos_min, refinements):
    """RANSAC plane: hypotheses from point triples scored on ``subset``, the best refined by
    least squares (smallest eigenvector of the inliers' covariance) ``refinements`` times.
    Returns (normal, d, inlier mask, found)."""
    best_score, best_n, best_d = -1, np.zeros(3), 0.0
    Xt, Nt = _columns(X, subset), _columns(N, subset)
    m = subset.shape[0]
    for h in range(triples.shape[0]):
        a, b, c = X[triples[h, 0]], X[triples[h, 1]], X[triples[h, 2]]
        ux, uy, uz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
        vx, vy, vz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
        nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if norm < 1e-12:
            continue
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        d = -(nx * a[0] + ny * a[1] + nz * a[2])
        score = 0
        for k in range(m):  # branch-free over contiguous columns: vectorised
            r = abs(Xt[0, k] * nx + Xt[1, k] * ny + Xt[2, k] * nz + d)
            c = abs(Nt[0, k] * nx + Nt[1, k] * ny + Nt[2, k] * nz)
            score += (r < dist) & (c > cos_min)
        if score > best_score:
            best_score = score
            best_n[0], best_n[1], best_n[2], best_d = nx, ny, nz, d
    mask = np.zeros(X.shape[0], np.bool_)
    if best_score < 0:
        return best_n, best_d, mask, False
    for _ in range(refinements):
        count = _plane_inliers(X, N, best_n[0], best_n[1], best_n[2], best_d, dist, cos_min, mask)
        if count < 3:
            return best_n, best_d, mask, False
        mean = np.zeros(3)
        for i in range(X.shape[0]):
            if mask[i]:
                for a in range(3):
                    mean[a] += X[i, a]
        mean /= count
        cov = np.zeros((3, 3))
        for i in range(X.shape[0]):
            if mask[i]:
                for a in range(3):
                    da = X[i, a] - mean[a]
                    for b in range(a, 3):
                        cov[a, b] += da * (X[i, b] - mean[b])
        for a in range(3):
            for b in range(a):
                cov[a, b] = cov[b, a]
        _, v = np.linalg.eigh(cov)
        best_n = v[:, 0].copy()
        best_d = -(best_n[0] * mean[0] + best_n[1] * mean[1] + best_n[2] * mean[2])
    _plane_inliers(X, N, best_n[0], best_n[1], best_n[2], best_d, dist, cos_min, mask)
    return best_n, best_d, mask, True


@njit(cache=True, nogil=True, inline="always")
def _radial(vx: float, vy: float, vz: float, ax: float, ay: float, az: float):
    """The part of v across the unit axis a, and its length: (rx, ry, rz, |r|)."""
    t = vx * ax + vy * ay + vz * az
    rx, ry, rz = vx - t * ax, vy - t * ay, vz - t * az
    return rx, ry, rz, math.sqrt(rx * rx + ry * ry + rz * rz)


@njit(cache=True, nogil=True)
def score_cylinders(X, N, subset, centers, axes, radii, dist, cos_min):
    """Inliers of each cylinder hypothesis among ``subset``."""
    out = np.zeros(radii.shape[0], np.int64)
    Xt, Nt = _columns(X, subset), _columns(N, subset)
    for h in range(radii.shape[0]):
        cx, cy, cz = centers[h, 0], centers[h, 1], centers[h, 2]
        ax, ay, az = axes[h, 0], axes[h, 1], axes[h, 2]
        score = 0
        for k in range(subset.shape[0]):  # branch-free: vectorised
            rx, ry, rz, r = _radial(Xt[0, k] - cx, Xt[1, k] - cy, Xt[2, k] - cz, ax, ay, az)
            cos = abs(Nt[0, k] * rx + Nt[1, k] * ry + Nt[2, k] * rz) / max(r, 1e-9)
            score += (r >= 1e-9) & (abs(r - radii[h]) < dist) & (cos > cos_min)
        out[h] = score
    return out


@njit(cache=True, nogil=True)
def score_spheres(X, N, subset, centers, radii, dist, cos_min):
    """Inliers of each sphere hypothesis among ``subset``."""
    out = np.zeros(radii.shape[0], np.int64)
    Xt, Nt = _columns(X, subset), _columns(N, subset)
    for h in range(radii.shape[0]):
        cx, cy, cz = centers[h, 0], centers[h, 1], centers[h, 2]
        score = 0
        for k in range(subset.shape[0]):  # branch-free: vectorised
            vx, vy, vz = Xt[0, k] - cx, Xt[1, k] - cy, Xt[2, k] - cz
            r = math.sqrt(vx * vx + vy * vy + vz * vz)
            cos = abs(Nt[0, k] * vx + Nt[1, k] * vy + Nt[2, k] * vz) / max(r, 1e-9)
            score += (r >= 1e-9) & (abs(r - radii[h]) < dist) & (cos > cos_min)
        out[h] = score
    return out


@njit(cache=True, nogil=True)
def cylinder_hypotheses(X, N, i, j, sin_min, r_min, r_max):
    """Cylinders from pairs of oriented points (``ransac.fit_cylinder``): the axis n1 × n2
    (pairs less than ``sin_min`` apart in normal dropped), the centre where the two normal
    lines come closest across the axis, the radius from it to p1, kept within (r_min, r_max).
    Returns (centers, axes, radii)."""
    k = i.shape[0]
    centers, axes, radii = np.empty((k, 3)), np.empty((k, 3)), np.empty(k)
    m = 0
    for h in range(k):
        p1, n1, p2, n2 = X[i[h]], N[i[h]], X[j[h]], N[j[h]]
        ax = n1[1] * n2[2] - n1[2] * n2[1]
        ay = n1[2] * n2[0] - n1[0] * n2[2]
        az = n1[0] * n2[1] - n1[1] * n2[0]
        s = math.sqrt(ax * ax + ay * ay + az * az)
        if not s > sin_min:
            continue
        ax, ay, az = ax / s, ay / s, az / s
        # the normals and the points' offset projected across the axis
        t1 = n1[0] * ax + n1[1] * ay + n1[2] * az
        m1 = (n1[0] - t1 * ax, n1[1] - t1 * ay, n1[2] - t1 * az)
        t2 = n2[0] * ax + n2[1] * ay + n2[2] * az
        m2 = (n2[0] - t2 * ax, n2[1] - t2 * ay, n2[2] - t2 * az)
        dx, dy, dz = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
        tw = dx * ax + dy * ay + dz * az
        w = (dx - tw * ax, dy - tw * ay, dz - tw * az)
        a = m1[0] * m1[0] + m1[1] * m1[1] + m1[2] * m1[2]
        b = m1[0] * m2[0] + m1[1] * m2[1] + m1[2] * m2[2]
        c = m2[0] * m2[0] + m2[1] * m2[1] + m2[2] * m2[2]
        e = m1[0] * w[0] + m1[1] * w[1] + m1[2] * w[2]
        f = m2[0] * w[0] + m2[1] * w[1] + m2[2] * w[2]
        den = a * c - b * b
        if not den > 1e-9:
            continue
        t = (b * f - c * e) / den
        cx, cy, cz = p1[0] + t * n1[0], p1[1] + t * n1[1], p1[2] + t * n1[2]
        r = _radial(p1[0] - cx, p1[1] - cy, p1[2] - cz, ax, ay, az)[3]
        if not (r > r_min and r < r_max):
            continue
        centers[m, 0], centers[m, 1], centers[m, 2] = cx, cy, cz
        axes[m, 0], axes[m, 1], axes[m, 2] = ax, ay, az
        radii[m] = r
        m += 1
    return centers[:m], axes[:m], radii[:m]


@njit(cache=True, nogil=True)
def sphere_hypotheses(X, N, i, j, r_min, r_max):
    """Spheres from pairs of oriented points (``ransac.fit_sphere``): the centre midway between
    the closest points of the two normal lines, kept where those lie within a fifth of the
    radius of each other and the radius within (r_min, r_max). Returns (centers, radii)."""
    k = i.shape[0]
    centers, radii = np.empty((k, 3)), np.empty(k)
    m = 0
    for h in range(k):
        p1, n1, p2, n2 = X[i[h]], N[i[h]], X[j[h]], N[j[h]]
        wx, wy, wz = p1[0] - p2[0], p1[1] - p2[1], p1[2] - p2[2]
        a = n1[0] * n1[0] + n1[1] * n1[1] + n1[2] * n1[2]
        b = n1[0] * n2[0] + n1[1] * n2[1] + n1[2] * n2[2]
        c = n2[0] * n2[0] + n2[1] * n2[1] + n2[2] * n2[2]
        e = n1[0] * wx + n1[1] * wy + n1[2] * wz
        f = n2[0] * wx + n2[1] * wy + n2[2] * wz
        den = a * c - b * b
        if not den > 1e-6:
            continue
        t, s = (b * f - c * e) / den, (a * f - b * e) / den
        q1 = (p1[0] + t * n1[0], p1[1] + t * n1[1], p1[2] + t * n1[2])
        q2 = (p2[0] + s * n2[0], p2[1] + s * n2[1], p2[2] + s * n2[2])
        cx, cy, cz = (q1[0] + q2[0]) / 2, (q1[1] + q2[1]) / 2, (q1[2] + q2[2]) / 2
        d1 = math.sqrt((p1[0] - cx) ** 2 + (p1[1] - cy) ** 2 + (p1[2] - cz) ** 2)
        d2 = math.sqrt((p2[0] - cx) ** 2 + (p2[1] - cy) ** 2 + (p2[2] - cz) ** 2)
        r = (d1 + d2) / 2
        gap = math.sqrt((q1[0] - q2[0]) ** 2 + (q1[1] - q2[1]) ** 2 + (q1[2] - q2[2]) ** 2)
        if not (gap < 0.2 * r and r > r_min and r < r_max):
            continue
        centers[m, 0], centers[m, 1], centers[m, 2] = cx, cy, cz
        radii[m] = r
        m += 1
    return centers[:m], radii[:m]


@njit(cache=True, nogil=True)
def cylinder_inliers(X, N, center, axis, radius, dist, cos_min):
    """The points within ``dist`` of the cylinder whose normal is within the angle of the
    radial direction (``ransac.cylinder_residuals`` thresholded), as a mask."""
    n = X.shape[0]
    out = np.zeros(n, np.bool_)
    cx, cy, cz = center[0], center[1], center[2]
    ax, ay, az = axis[0], axis[1], axis[2]
    for p in range(n):
        rx, ry, rz, r = _radial(X[p, 0] - cx, X[p, 1] - cy, X[p, 2] - cz, ax, ay, az)
        if abs(r - radius) < dist:
            cos = abs(N[p, 0] * rx + N[p, 1] * ry + N[p, 2] * rz) / max(r, 1e-9)
            out[p] = cos > cos_min
    return out


@njit(cache=True, nogil=True)
def sphere_inliers(X, N, center, radius, dist, cos_min):
    """``ransac.sphere_residuals`` thresholded, as a mask."""
    n = X.shape[0]
    out = np.zeros(n, np.bool_)
    for p in range(n):
        vx, vy, vz = X[p, 0] - center[0], X[p, 1] - center[1], X[p, 2] - center[2]
        r = math.sqrt(vx * vx + vy * vy + vz * vz)
        if abs(r - radius) < dist:
            out[p] = abs(N[p, 0] * vx + N[p, 1] * vy + N[p, 2] * vz) / max(r, 1e-9) > cos_min
    return out


@njit(cache=True, nogil=True, inline="always")
def _grey(r: float, g: float, b: float, limit: float) -> bool:
    """Saturation (max − min) / max below ``limit``."""
    hi = max(r, g, b)
    return hi <= 0 or (hi - min(r, g, b)) / hi < limit


@njit(cache=True, nogil=True)
def colour_edges(
    colours: np.ndarray,
    normals: np.ndarray,
    valid: np.ndarray,
    cos_same: float,
    threshold: float,
    chroma_threshold: float,
    dark: float,
    grey: float,
) -> np.ndarray:
    """(h, w) bool: material boundaries between a pixel and its right or lower neighbour.
    Either their chromaticity (rgb / (r + g + b)) differs by more than ``chroma_threshold``
    (shading scales a colour and keeps its chromaticity; pixels darker than ``dark`` have
    none to speak of), or, both grey (saturation under ``grey``: no hue to tell them apart)
    and on one surface orientation (normals within ``cos_same``), their brightness differs by
    more than ``threshold`` (0-255 RGB): across a crease shading alone changes it. A print in
    shades of one colour is no boundary. Where a normal is unknown (the image's rim) the
    surface is taken as one, so that an edge runs to the border."""
    h, w = valid.shape
    edge = np.zeros((h, w), np.bool_)
    t2, c2 = threshold * threshold, chroma_threshold * chroma_threshold
    for r in range(h):
        for c in range(w):
            if not valid[r, c]:
                continue
            a0, a1, a2 = float(colours[r, c, 0]), float(colours[r, c, 1]), float(colours[r, c, 2])
            sa = a0 + a1 + a2
            for dr, dc in ((0, 1), (1, 0)):
                r2, c2_ = r + dr, c + dc
                if r2 >= h or c2_ >= w or not valid[r2, c2_]:
                    continue
                b0 = float(colours[r2, c2_, 0])
                b1 = float(colours[r2, c2_, 1])
                b2 = float(colours[r2, c2_, 2])
                sb = b0 + b1 + b2
                marked = False
                if sa > dark and sb > dark:
                    x0, x1, x2 = a0 / sa - b0 / sb, a1 / sa - b1 / sb, a2 / sa - b2 / sb
                    marked = x0 * x0 + x1 * x1 + x2 * x2 > c2
                if not marked and _grey(a0, a1, a2, grey) and _grey(b0, b1, b2, grey):
                    dot = (
                        normals[r, c, 0] * normals[r2, c2_, 0]
                        + normals[r, c, 1] * normals[r2, c2_, 1]
                        + normals[r, c, 2] * normals[r2, c2_, 2]
                    )
                    na = abs(normals[r, c, 0]) + abs(normals[r, c, 1]) + abs(normals[r, c, 2])
                    nb = (
                        abs(normals[r2, c2_, 0])
                        + abs(normals[r2, c2_, 1])
                        + abs(normals[r2, c2_, 2])
                    )
                    unknown = na == 0 or nb == 0
                    if dot >= cos_same or unknown:
                        y0, y1, y2 = a0 - b0, a1 - b1, a2 - b2
                        marked = y0 * y0 + y1 * y1 + y2 * y2 > t2
                if marked:
                    edge[r, c] = True
                    edge[r2, c2_] = True
    return edge


@njit(cache=True, nogil=True)
def grow_labels(labels: np.ndarray, region: np.ndarray) -> np.ndarray:
    """Give every pixel of ``region`` (h, w; -1 outside any) that has no label (-1) the label
    of the nearest labelled pixel of the same region, by breadth-first growth over
    4-neighbours (multi-source: every labelled pixel starts at once)."""
    h, w = labels.shape
    out = labels.copy()
    queue = np.empty(h * w, np.int64)
    head = tail = 0
    for i in range(h * w):
        if out.flat[i] >= 0:
            queue[tail] = i
            tail += 1
    while head < tail:
        i = queue[head]
        head += 1
        r, c = i // w, i % w
        for dr, dc in ((0, 1), (1, 0), (0, -1), (-1, 0)):
            r2, c2 = r + dr, c + dc
            if (
                0 <= r2 < h
                and 0 <= c2 < w
                and out[r2, c2] < 0
                and region[r2, c2] >= 0
                and region[r2, c2] == region[r, c]
            ):
                out[r2, c2] = out[r, c]
                queue[tail] = r2 * w + c2
                tail += 1
    return out


@njit(cache=True, nogil=True)
def part_stats(
    parts: np.ndarray, labels: np.ndarray, colours: np.ndarray, m: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One pass over the grid: per part 1..m its pixel count, its region (the ``labels`` of
    its pixels; -1 for part 0) and its mean colour."""
    h, w = parts.shape
    size = np.zeros(m + 1, np.int64)
    region = np.full(m + 1, -1, np.int64)
    total = np.zeros((m + 1, 3))
    for r in range(h):
        for c in range(w):
            p = parts[r, c]
            if p == 0:
                continue
            size[p] += 1
            region[p] = labels[r, c]
            for k in range(3):
                total[p, k] += colours[r, c, k]
    for p in range(1, m + 1):
        if size[p]:
            for k in range(3):
                total[p, k] /= size[p]
    return size, region, total


@njit(cache=True, nogil=True, inline="always")
def _solve3(M: np.ndarray, v: np.ndarray, out: np.ndarray) -> bool:
    """M x = v for 3×3 M by Gaussian elimination with partial pivoting (LAPACK's gesv, as
    np.linalg.solve); False when M is singular. M and v are overwritten."""
    for k in range(3):
        p = k
        for i in range(k + 1, 3):
            if abs(M[i, k]) > abs(M[p, k]):
                p = i
        if M[p, k] == 0.0:
            return False
        if p != k:
            for j in range(3):
                M[k, j], M[p, j] = M[p, j], M[k, j]
            v[k], v[p] = v[p], v[k]
        for i in range(k + 1, 3):
            f = M[i, k] / M[k, k]
            for j in range(k, 3):
                M[i, j] -= f * M[k, j]
            v[i] -= f * v[k]
    for k in range(2, -1, -1):
        s = v[k]
        for j in range(k + 1, 3):
            s -= M[k, j] * out[j]
        out[k] = s / M[k, k]
    return True


@njit(cache=True, nogil=True)
def circle_fit(Q: np.ndarray, iterations: int) -> tuple[float, float, float, bool]:
    """Circle through 2D points: Kåsa's algebraic fit (2x·cx + 2y·cy + c = x² + y², least
    squares by the normal equations), then Gauss-Newton on the geometric distance
    |q − c| − r. Returns (cx, cy, r, ok); not ok where a system is singular."""
    n = Q.shape[0]
    M, v, x = np.zeros((3, 3)), np.zeros(3), np.zeros(3)
    for i in range(n):
        a = (2.0 * Q[i, 0], 2.0 * Q[i, 1], 1.0)
        b = Q[i, 0] * Q[i, 0] + Q[i, 1] * Q[i, 1]
        for r in range(3):
            v[r] += a[r] * b
            for c in range(3):
                M[r, c] += a[r] * a[c]
    if not _solve3(M, v, x):
        return 0.0, 0.0, 0.0, False
    cx, cy = x[0], x[1]
    radius = math.sqrt(max(x[2] + cx * cx + cy * cy, 0.0))
    for _ in range(iterations):
        M[:] = 0.0
        v[:] = 0.0
        for i in range(n):
            dx, dy = Q[i, 0] - cx, Q[i, 1] - cy
            dist = max(math.sqrt(dx * dx + dy * dy), 1e-9)
            a = (-dx / dist, -dy / dist, -1.0)
            b = radius - dist
            for r in range(3):
                v[r] += a[r] * b
                for c in range(3):
                    M[r, c] += a[r] * a[c]
        if not _solve3(M, v, x):
            return cx, cy, abs(radius), False
        cx, cy, radius = cx + x[0], cy + x[1], radius + x[2]
        if max(abs(x[0]), abs(x[1]), abs(x[2])) < 1e-6:
            break
    return cx, cy, abs(radius), True


@njit(cache=True, nogil=True)
def _box_coords(pixels: np.ndarray, width: int, border: int):
    """Rows and columns of ``pixels`` (flat indices into a grid ``width`` wide) in their
    bounding box grown by ``border`` on every side, and that box's height and width."""
    n = pixels.shape[0]
    rows, cols = np.empty(n, np.int64), np.empty(n, np.int64)
    r0, r1, c0, c1 = pixels[0] // width, -1, width, -1
    for i in range(n):
        r = pixels[i] // width
        c = pixels[i] - r * width
        rows[i], cols[i] = r, c
        r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    for i in range(n):
        rows[i] -= r0 - border
        cols[i] -= c0 - border
    return rows, cols, r1 - r0 + 1 + 2 * border, c1 - c0 + 1 + 2 * border


@njit(cache=True, nogil=True)
def near(pixels: np.ndarray, mask: np.ndarray, width: int) -> np.ndarray:
    """Which of ``pixels`` (flat indices into a grid ``width`` wide) are within one
    grid step (8-neighbourhood, itself included) of a ``mask``-ed one: a 3×3 dilation of the
    masked pixels read at ``pixels``, on the pixels' bounding box only."""
    n = pixels.shape[0]
    out = np.zeros(n, np.bool_)
    if n == 0:
        return out
    rows, cols, h, w = _box_coords(pixels, width, 1)  # one pixel of border all round
    grid = np.zeros((h, w), np.bool_)
    for i in range(n):
        if mask[i]:
            grid[rows[i], cols[i]] = True
    for i in range(n):
        r, c = rows[i], cols[i]
        out[i] = (
            grid[r - 1, c - 1] or grid[r - 1, c] or grid[r - 1, c + 1]
            or grid[r, c - 1] or grid[r, c] or grid[r, c + 1]
            or grid[r + 1, c - 1] or grid[r + 1, c] or grid[r + 1, c + 1]
        )  # fmt: skip
    return out


@njit(cache=True, nogil=True)
def back_project(
    z: np.ndarray, valid: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int,
    R: np.ndarray, t: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """World points (h, w, 3) float32 of a (strided) depth grid: pixel (v, u) of the grid is
    (stride·u, stride·v) of the image; NaN where not ``valid``."""
    h, w = z.shape
    out = np.empty((h, w, 3), np.float32)
    for v in range(h):
        y_over_z = (np.float32(stride * v) - np.float32(cy)) / np.float32(fy)
        for u in range(w):
            if not valid[v, u]:
                out[v, u, 0] = out[v, u, 1] = out[v, u, 2] = np.nan
                continue
            d = z[v, u]
            x = (np.float32(stride * u) - np.float32(cx)) / np.float32(fx) * d
            y = y_over_z * d
            for k in range(3):
                out[v, u, k] = R[k, 0] * x + R[k, 1] * y + R[k, 2] * d + t[k]
    return out


@njit(cache=True, nogil=True)
def grid_labels(pixels: np.ndarray, width: int) -> tuple[np.ndarray, int]:
    """The 8-connected components of ``pixels`` (flat indices into a grid ``width`` wide):
    each pixel's label (1 … n) and n, labels in the raster order of each component's
    first pixel, as ``scipy.ndimage.label`` numbers them."""
    n = pixels.shape[0]
    out = np.zeros(n, np.int64)
    if n == 0:
        return out, 0
    rows, cols, h, w = _box_coords(pixels, width, 0)
    member = np.zeros((h, w), np.bool_)
    for i in range(n):
        member[rows[i], cols[i]] = True
    label = np.zeros((h, w), np.int64)
    stack = np.empty(n, np.int64)
    count = 0
    for r in range(h):
        for c in range(w):
            if not member[r, c] or label[r, c] != 0:
                continue
            count += 1
            label[r, c] = count
            stack[0] = r * w + c
            top = 1
            while top > 0:
                top -= 1
                rr, cc = stack[top] // w, stack[top] % w
                for dr in range(-1, 2):
                    for dc in range(-1, 2):
                        y, x = rr + dr, cc + dc
                        if 0 <= y < h and 0 <= x < w and member[y, x] and label[y, x] == 0:
                            label[y, x] = count
                            stack[top] = y * w + x
                            top += 1
    for i in range(n):
        out[i] = label[rows[i], cols[i]]
    return out, count


@njit(cache=True, nogil=True)
def view_median(points: np.ndarray, pixels: np.ndarray, centre: np.ndarray) -> float:
    """np.median of the distances from the grid ``points`` (h·w, 3) at ``pixels`` to
    ``centre``: one pass instead of a gather, a norm and numpy's median (0.1 ms a call,
    twenty calls a frame)."""
    n = len(pixels)
    d = np.empty(n)
    for k in range(n):
        p = pixels[k]
        x = np.float64(points[p, 0]) - centre[0]
        y = np.float64(points[p, 1]) - centre[1]
        z = np.float64(points[p, 2]) - centre[2]
        d[k] = math.sqrt(x * x + y * y + z * z)
    d.sort()
    if n % 2:
        return d[n // 2]
    return (d[n // 2 - 1] + d[n // 2]) / 2


@njit(cache=True, nogil=True)
def plane_coords(
    points: np.ndarray, e1: np.ndarray, e2: np.ndarray, normal: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """A plane's points in its frame: their mean o, their in-plane coordinates
    ((p − o)·e1, (p − o)·e2) and the least and greatest height (p − o)·normal."""
    n = points.shape[0]
    o = np.zeros(3)
    for i in range(n):
        for a in range(3):
            o[a] += points[i, a]
    o /= n
    Q = np.empty((n, 2))
    lo, hi = np.inf, -np.inf
    for i in range(n):
        dx, dy, dz = points[i, 0] - o[0], points[i, 1] - o[1], points[i, 2] - o[2]
        Q[i, 0] = dx * e1[0] + dy * e1[1] + dz * e1[2]
        Q[i, 1] = dx * e2[0] + dy * e2[1] + dz * e2[2]
        h = dx * normal[0] + dy * normal[1] + dz * normal[2]
        lo = min(lo, h)
        hi = max(hi, h)
    return o, Q, lo, hi


@njit(cache=True, nogil=True)
def rectangle_span(Q: np.ndarray, d1: np.ndarray) -> tuple[float, float, float, float]:
    """Least and greatest of Q·d1 and of Q·d2, d2 = d1 turned by 90°."""
    u0, u1, v0, v1 = np.inf, -np.inf, np.inf, -np.inf
    for i in range(Q.shape[0]):
        u = Q[i, 0] * d1[0] + Q[i, 1] * d1[1]
        v = -Q[i, 0] * d1[1] + Q[i, 1] * d1[0]
        u0, u1, v0, v1 = min(u0, u), max(u1, u), min(v0, v), max(v1, v)
    return u0, u1, v0, v1


@njit(cache=True, nogil=True, inline="always")
def _fifth(x: np.ndarray) -> float:
    """``np.percentile(x, 5)`` of a non-empty array (linear interpolation, numpy's rounding):
    ``relations.fifth_percentile`` on a sorted copy."""
    s = np.sort(x)
    n = s.shape[0]
    v = 0.05 * n + 0.95 - 1
    i = min(max(math.floor(v), 0), n - 1)
    j = min(i + 1, n - 1)
    g = v - math.floor(v)
    a, b = s[i], s[j]
    return b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g


@njit(cache=True, nogil=True)
def face_contact(points, center, R, half, contact):
    """``relations._face_contact`` on one primitive's (sampled) points against another's box
    (centre, rotation with the axes as columns, half extents). Returns (found, outward normal,
    contact point, overlap share) of the best touched face."""
    n = points.shape[0]
    local = np.empty((n, 3))
    for p in range(n):
        dx, dy, dz = points[p, 0] - center[0], points[p, 1] - center[1], points[p, 2] - center[2]
        for k in range(3):
            local[p, k] = dx * R[0, k] + dy * R[1, k] + dz * R[2, k]
    found, best_share = False, 0.0
    best_n, best_point = np.zeros(3), np.zeros(3)
    over = np.empty(n, np.bool_)
    for k in range(3):
        k1, k2 = (k + 1) % 3, (k + 2) % 3
        count = 0
        for p in range(n):
            over[p] = (abs(local[p, k1]) <= half[k1] + contact) and (
                abs(local[p, k2]) <= half[k2] + contact
            )
            count += over[p]
        share = count / n
        if share < 0.05:
            continue
        for sign in (1.0, -1.0):
            d = np.empty(count)
            m = 0
            for p in range(n):
                if over[p]:
                    d[m] = sign * local[p, k] - half[k]
                    m += 1
            if _fifth(d) < -contact / 2 or d.min() > contact:
                continue
            beyond = np.empty(n)
            for p in range(n):
                beyond[p] = sign * local[p, k] - half[k]
            if _fifth(beyond) < -contact / 2:
                continue  # the other reaches past the face's plane beside it
            if found and share <= best_share:
                continue
            found, best_share = True, share
            for a in range(3):
                best_n[a] = sign * R[a, k]
                best_point[a] = center[a] + best_n[a] * half[k]
            touching = 0
            acc = np.zeros(3)
            m = 0
            for p in range(n):
                if over[p]:
                    if abs(d[m]) < contact:
                        touching += 1
                        for a in range(3):
                            acc[a] += points[p, a]
                    m += 1
            if touching > 0:
                best_point = acc / touching
    return found, best_n, best_point, best_share


@njit(cache=True, nogil=True)
def _solve_small(M: np.ndarray, v: np.ndarray, out: np.ndarray) -> bool:
    """M x = v for a small square M by Gaussian elimination with partial pivoting (as
    ``_solve3``, any size); False when M is singular. M and v are overwritten."""
    n = M.shape[0]
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(M[i, k]) > abs(M[p, k]):
                p = i
        if M[p, k] == 0.0:
            return False
        if p != k:
            for j in range(n):
                M[k, j], M[p, j] = M[p, j], M[k, j]
            v[k], v[p] = v[p], v[k]
        for i in range(k + 1, n):
            f = M[i, k] / M[k, k]
            for j in range(k, n):
                M[i, j] -= f * M[k, j]
            v[i] -= f * v[k]
    for k in range(n - 1, -1, -1):
        s = v[k]
        for j in range(k + 1, n):
            s -= M[k, j] * out[j]
        out[k] = s / M[k, k]
    return True


@njit(cache=True, nogil=True)
def cylinder_refine(X, N, mask, axis):
    """``ransac.refine_cylinder`` on the masked points in one pass: the axis least aligned
    with their normals (the given one where they sweep no arc), centre and radius by a circle
    fit across it. Returns (centre, axis, radius, ok); not ok where the circle's system is
    singular (the caller falls back to numpy's least squares)."""
    NtN = np.zeros((3, 3))
    o = np.zeros(3)
    m = 0
    for p in range(X.shape[0]):
        if mask[p]:
            m += 1
            for a in range(3):
                o[a] += X[p, a]
                for b in range(3):
                    NtN[a, b] += N[p, a] * N[p, b]
    o /= max(m, 1)
    w, v = np.linalg.eigh(NtN)
    ax = v[:, 0].copy() if w[1] > 4 * max(w[0], 1e-12) else axis.copy()
    ax /= math.sqrt(ax[0] * ax[0] + ax[1] * ax[1] + ax[2] * ax[2])
    rx, ry, rz = (1.0, 0.0, 0.0) if abs(ax[0]) < 0.9 else (0.0, 1.0, 0.0)
    e1 = np.array([ax[1] * rz - ax[2] * ry, ax[2] * rx - ax[0] * rz, ax[0] * ry - ax[1] * rx])
    norm = math.sqrt(e1 @ e1)
    e1 = e1 / norm if norm > 1e-12 else np.zeros(3)
    e2 = np.array([ax[1] * e1[2] - ax[2] * e1[1], ax[2] * e1[0] - ax[0] * e1[2],
                   ax[0] * e1[1] - ax[1] * e1[0]])  # fmt: skip
    Q = np.empty((m, 2))
    k = 0
    for p in range(X.shape[0]):
        if mask[p]:
            dx, dy, dz = X[p, 0] - o[0], X[p, 1] - o[1], X[p, 2] - o[2]
            Q[k, 0] = dx * e1[0] + dy * e1[1] + dz * e1[2]
            Q[k, 1] = dx * e2[0] + dy * e2[1] + dz * e2[2]
            k += 1
    cx, cy, r, ok = circle_fit(Q, 4)
    return o + cx * e1 + cy * e2, ax, r, ok


@njit(cache=True, nogil=True)
def sphere_refine(X, mask):
    """``ransac.refine_sphere`` on the masked points (algebraic fit, normal equations).
    Returns (centre, radius, ok); not ok where the system is singular."""
    M, v, x = np.zeros((4, 4)), np.zeros(4), np.zeros(4)
    for p in range(X.shape[0]):
        if mask[p]:
            a = (2.0 * X[p, 0], 2.0 * X[p, 1], 2.0 * X[p, 2], 1.0)
            b = X[p, 0] * X[p, 0] + X[p, 1] * X[p, 1] + X[p, 2] * X[p, 2]
            for r in range(4):
                v[r] += a[r] * b
                for c in range(4):
                    M[r, c] += a[r] * a[c]
    if not _solve_small(M, v, x):
        return np.zeros(3), 0.0, False
    c = x[:3].copy()
    return c, math.sqrt(max(x[3] + c[0] * c[0] + c[1] * c[1] + c[2] * c[2], 0.0)), True


@njit(cache=True, nogil=True)
def plane_band(X, normal, d, lo_q, hi_q):
    """``np.percentile(X @ normal + d, (lo_q, hi_q))`` (linear interpolation, numpy's
    rounding): the band of a plane's inliers (``primitives._flat_enough``)."""
    n = X.shape[0]
    s = np.empty(n)
    for p in range(n):
        s[p] = X[p, 0] * normal[0] + X[p, 1] * normal[1] + X[p, 2] * normal[2] + d
    qs = (lo_q / 100, hi_q / 100)
    kth = np.empty(4, np.int64)
    for k in range(2):
        i = min(max(math.floor(qs[k] * (n - 1)), 0), n - 1)
        kth[2 * k], kth[2 * k + 1] = i, min(i + 1, n - 1)
    s = np.partition(s, np.unique(kth))  # the four order statistics in place, not a sort
    out = np.empty(2)
    for k in range(2):
        v = qs[k] * (n - 1)
        g = v - math.floor(v)
        a, b = s[kth[2 * k]], s[kth[2 * k + 1]]
        out[k] = b - (b - a) * (1 - g) if g >= 0.5 else a + (b - a) * g
    return out


@njit(cache=True, nogil=True)
def plane_inliers(X, N, normal, d, dist, cos_min):
    """``ransac.plane_residuals`` thresholded, as a mask."""
    out = np.empty(X.shape[0], np.bool_)
    _plane_inliers(X, N, normal[0], normal[1], normal[2], d, dist, cos_min, out)
    return out


@njit(cache=True, nogil=True)
def region_spans(points, labels, n):
    """The largest side of each region's axis-aligned box (labels 0..n-1, -1 outside):
    ``np.ptp(points[labels == r], axis=0).max()`` of every region in one pass."""
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    h, w = labels.shape
    for i in range(h):
        for j in range(w):
            r = labels[i, j]
            if r < 0:
                continue
            for a in range(3):
                v = points[i, j, a]
                if v < lo[r, a]:
                    lo[r, a] = v
                if v > hi[r, a]:
                    hi[r, a] = v
    out = np.zeros(n)
    for r in range(n):
        out[r] = max(hi[r, 0] - lo[r, 0], hi[r, 1] - lo[r, 1], hi[r, 2] - lo[r, 2])
    return out


@njit(cache=True, nogil=True)
def normal_arc(N, e1, e2):
    """``ransac.cylinder_arc`` with the axis' frame (e1, e2) given: the angle (rad) the
    normals sweep around the axis, 2π less the largest gap between their angles. The gap by
    buckets (the maximum-gap algorithm: n buckets over the angles' range, a gap wider than
    a bucket runs between buckets' ends), not a sort: linear in the points."""
    n = N.shape[0]
    if n < 2:
        return 0.0
    two_pi = 2 * np.pi
    ang = np.empty(n)
    for p in range(n):
        a = math.atan2(N[p, 0] * e2[0] + N[p, 1] * e2[1] + N[p, 2] * e2[2],
                       N[p, 0] * e1[0] + N[p, 1] * e1[1] + N[p, 2] * e1[2])  # fmt: skip
        ang[p] = np.mod(a, two_pi)
    lo, hi = ang.min(), ang.max()
    gap = lo + two_pi - hi  # across 0
    if hi > lo:
        width = (hi - lo) / n
        b_lo = np.full(n, np.inf)
        b_hi = np.full(n, -np.inf)
        for p in range(n):
            b = min(int((ang[p] - lo) / width), n - 1)
            b_lo[b] = min(b_lo[b], ang[p])
            b_hi[b] = max(b_hi[b], ang[p])
        last = b_hi[0]
        for b in range(1, n):
            if b_lo[b] <= b_hi[b]:
                gap = max(gap, b_lo[b] - last)
                last = b_hi[b]
    return two_pi - gap


@njit(cache=True, nogil=True)
def normal_spread(N):
    """``ransac.sphere_spread`` in one pass: the smaller angular spread (deg) of the normals
    across their two main directions."""
    n = N.shape[0]
    if n < 3:
        return 0.0
    m = np.zeros(3)
    for p in range(n):
        for a in range(3):
            m[a] += N[p, a]
    m /= n
    norm = math.sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2])
    m = m / norm if norm > 1e-12 else np.zeros(3)
    C = np.zeros((3, 3))
    for p in range(n):
        t = N[p, 0] * m[0] + N[p, 1] * m[1] + N[p, 2] * m[2]
        d0, d1, d2 = N[p, 0] - t * m[0], N[p, 1] - t * m[1], N[p, 2] - t * m[2]
        C[0, 0] += d0 * d0
        C[0, 1] += d0 * d1
        C[0, 2] += d0 * d2
        C[1, 1] += d1 * d1
        C[1, 2] += d1 * d2
        C[2, 2] += d2 * d2
    C[1, 0], C[2, 0], C[2, 1] = C[0, 1], C[0, 2], C[1, 2]
    w = np.linalg.eigvalsh(C / n)
    return math.degrees(math.asin(math.sqrt(min(max(w[1], 0.0), 1.0))))
