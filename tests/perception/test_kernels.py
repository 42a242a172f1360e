"""The compiled kernels (and other fast paths) against the numpy/scipy code they replace: the
same answers."""

from __future__ import annotations

import numpy as np
import pytest

from services.perception import kernels, obb, primitives, ransac, relations
from services.perception.cloud import organized_cloud
from services.perception.relations import fifth_percentile

SHAPE = (240, 320)


@pytest.mark.parametrize("seed", range(6))
def test_near_is_a_3x3_dilation_of_the_mask(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 20_000))
    pixels = np.sort(rng.choice(SHAPE[0] * SHAPE[1], n, replace=False))
    if seed % 2:  # a compact blob, as a segment is
        pixels = np.unique(rng.integers(0, 3000, n) + int(rng.integers(0, 60_000)))
    mask = rng.random(len(pixels)) < rng.random()
    got = primitives._near(pixels, mask, SHAPE)
    assert got.dtype == bool and len(got) == len(pixels)
    assert (got == primitives._near_numpy(pixels, mask, SHAPE)).all()
    assert got[mask].all()  # a masked pixel is near itself


def test_near_on_the_grid_border_and_of_nothing():
    corner = np.array([0, 1, SHAPE[1], SHAPE[1] * SHAPE[0] - 1])
    got = primitives._near(corner, np.array([True, False, False, False]), SHAPE)
    assert got.tolist() == [True, True, True, False]
    assert primitives._near(corner, np.zeros(4, bool), SHAPE).sum() == 0


@pytest.mark.parametrize("arc_rad", [0.4, 1.5, 6.28])
def test_circle_fit_matches_the_numpy_fit_and_the_truth(arc_rad):
    rng = np.random.default_rng(int(arc_rad * 10))
    theta = rng.uniform(0, arc_rad, 800)
    Q = np.column_stack([0.3 + 0.04 * np.cos(theta), -0.2 + 0.04 * np.sin(theta)])
    Q += rng.normal(scale=0.0003, size=Q.shape)
    (c, r), (c_ref, r_ref) = ransac._circle_fit(Q), ransac._circle_fit_numpy(Q)
    assert np.abs(c - c_ref).max() < 1e-7 and abs(r - r_ref) < 1e-7
    assert abs(r - 0.04) < 0.003 and np.linalg.norm(c - [0.3, -0.2]) < 0.005


def test_circle_fit_of_coincident_points_falls_back_without_raising():
    c, r = ransac._circle_fit(np.ones((20, 2)))
    assert np.isfinite(c).all() and np.isfinite(r)


def test_back_projection_matches_the_pinhole_model():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 2.5, (480, 640)).astype(np.float32)
    depth[::7, ::5] = 0.0  # no return
    depth[4, 6] = np.nan
    a = np.radians(30)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
    T[:3, 3] = [0.5, -1.0, 1.2]
    fx, fy, cx, cy = 525.0, 520.0, 319.5, 239.5
    cloud = organized_cloud(depth, None, fx, fy, cx, cy, T)
    z = depth[::2, ::2].astype(np.float64)
    v, u = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    cam = np.stack([(2 * u - cx) / fx * z, (2 * v - cy) / fy * z, z], axis=-1)
    expected = cam @ T[:3, :3].T + T[:3, 3]
    ok = cloud.valid
    assert ok.sum() < ok.size and not ok[2, 3]  # (4, 6) is grid (2, 3): NaN, masked
    assert np.isnan(cloud.points[~ok]).all()
    assert np.abs(cloud.points[ok] - expected[ok]).max() < 1e-5


@pytest.mark.parametrize("n", [1, 2, 3, 20, 21, 400, 1999])
def test_fifth_percentile_is_numpys(n):
    rng = np.random.default_rng(n)
    for x in (rng.normal(size=n), np.round(rng.normal(size=n), 1)):
        assert fifth_percentile(x) == pytest.approx(float(np.percentile(x, 5)), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_grid_labels_number_components_as_scipy_does(seed):
    from scipy import ndimage

    from services.perception import kernels

    rng = np.random.default_rng(seed)
    pixels = np.sort(rng.choice(SHAPE[0] * SHAPE[1], int(rng.integers(1, 30_000)), replace=False))
    if seed % 2:  # in no particular order
        rng.shuffle(pixels)
    own, n = kernels.grid_labels(pixels, SHAPE[1])
    rows, cols = np.divmod(pixels, SHAPE[1])
    grid = np.zeros((rows.max() - rows.min() + 1, cols.max() - cols.min() + 1), bool)
    grid[rows - rows.min(), cols - cols.min()] = True
    labels, n_ref = ndimage.label(grid, structure=np.ones((3, 3), bool))
    assert n == n_ref > 1
    assert (own == labels[rows - rows.min(), cols - cols.min()]).all()


def _cylinder_hypotheses_numpy(X, N, i, j, r_min, r_max):
    """``fit_cylinder``'s hypotheses as numpy computed them before the kernel."""
    p1, n1, p2, n2 = X[i], N[i], X[j], N[j]
    axes = np.cross(n1, n2)
    s = np.linalg.norm(axes, axis=1)
    ok = s > np.sin(np.radians(5))
    p1, n1, p2, n2, axes = p1[ok], n1[ok], p2[ok], n2[ok], axes[ok] / s[ok, None]
    proj = lambda v: v - np.einsum("ij,ij->i", v, axes)[:, None] * axes  # noqa: E731
    m1, m2, w = proj(n1), proj(n2), proj(p1 - p2)
    a, b, c = (m1 * m1).sum(1), (m1 * m2).sum(1), (m2 * m2).sum(1)
    e, f = (m1 * w).sum(1), (m2 * w).sum(1)
    den = a * c - b * b
    good = den > 1e-9
    t = np.where(good, (b * f - c * e) / np.where(good, den, 1), 0)
    centers = p1 + t[:, None] * n1
    radii = np.linalg.norm(proj(p1 - centers), axis=1)
    good &= (radii > r_min) & (radii < r_max)
    return centers[good], axes[good], radii[good]


def _sphere_hypotheses_numpy(X, N, i, j, r_min, r_max):
    p1, n1, p2, n2 = X[i], N[i], X[j], N[j]
    w = p1 - p2
    a, b, c = (n1 * n1).sum(1), (n1 * n2).sum(1), (n2 * n2).sum(1)
    e, f = (n1 * w).sum(1), (n2 * w).sum(1)
    den = a * c - b * b
    good = den > 1e-6
    den = np.where(good, den, 1)
    t, s = (b * f - c * e) / den, (a * f - b * e) / den
    q1, q2 = p1 + t[:, None] * n1, p2 + s[:, None] * n2
    centers = (q1 + q2) / 2
    radii = (np.linalg.norm(p1 - centers, axis=1) + np.linalg.norm(p2 - centers, axis=1)) / 2
    good &= (np.linalg.norm(q1 - q2, axis=1) < 0.2 * radii) & (radii > r_min) & (radii < r_max)
    return centers[good], radii[good]


def _oriented_points(seed: int, curved: str) -> tuple[np.ndarray, np.ndarray]:
    """400 noisy points with normals on a cylinder or sphere patch, or on a plane."""
    rng = np.random.default_rng(seed)
    u, v = rng.uniform(-1.0, 1.0, 400), rng.uniform(-0.6, 0.6, 400)
    if curved == "cylinder":
        N = np.column_stack([np.cos(u), np.sin(u), np.zeros(400)])
        X = 0.05 * N + np.column_stack([np.zeros((400, 2)), v / 5])
    elif curved == "sphere":
        N = np.column_stack([np.cos(u) * np.cos(v), np.sin(u) * np.cos(v), np.sin(v)])
        X = 0.06 * N
    else:
        N = np.tile([0.0, 0.0, 1.0], (400, 1))
        X = np.column_stack([u / 5, v / 5, np.zeros(400)])
    X = X + np.array([1.0, 0.2, 0.8]) + rng.normal(scale=0.001, size=X.shape)
    N = N + rng.normal(scale=0.05, size=N.shape)
    return X, N / np.linalg.norm(N, axis=1, keepdims=True)


@pytest.mark.parametrize("shape", ["cylinder", "sphere", "plane"])
@pytest.mark.parametrize("seed", range(3))
def test_curved_hypotheses_and_inliers_are_numpys(shape, seed):
    """The compiled hypotheses of the cylinder and sphere RANSAC are numpy's (the same ones,
    in order, to 1e-12), and so are the compiled inlier masks of a hypothesis."""
    from services.perception import kernels

    X, N = _oriented_points(seed, shape)
    rng = np.random.default_rng(seed)
    i, j = ransac._pairs(rng, len(X), 64)
    got = kernels.cylinder_hypotheses(X, N, i, j, ransac.SIN_MIN, 0.01, 0.5)
    want = _cylinder_hypotheses_numpy(X, N, i, j, 0.01, 0.5)
    assert len(got[2]) == len(want[2]) and (shape != "cylinder" or len(want[2]) > 20)
    for g, w in zip(got, want, strict=True):
        assert np.abs(g - w).max(initial=0) < 1e-12
    got_s = kernels.sphere_hypotheses(X, N, i, j, 0.01, 0.5)
    want_s = _sphere_hypotheses_numpy(X, N, i, j, 0.01, 0.5)
    assert len(got_s[1]) == len(want_s[1]) and (shape != "sphere" or len(want_s[1]) > 20)
    for g, w in zip(got_s, want_s, strict=True):
        assert np.abs(g - w).max(initial=0) < 1e-12
    for h in range(min(5, len(want[2]))):
        c, a, r = want[0][h], want[1][h], float(want[2][h])
        res, cos = ransac.cylinder_residuals(X, N, c, a, r)
        mask = kernels.cylinder_inliers(X, N, c, a, r, 0.004, 0.9)
        assert (mask == ((res < 0.004) & (cos > 0.9))).all()
    for h in range(min(5, len(want_s[1]))):
        c, r = want_s[0][h], float(want_s[1][h])
        res, cos = ransac.sphere_residuals(X, N, c, r)
        mask = kernels.sphere_inliers(X, N, c, r, 0.004, 0.9)
        assert (mask == ((res < 0.004) & (cos > 0.9))).all()
    fit = ransac.fit_cylinder(X, N, rng, 0.004, 0.9, 0.01, 0.5)
    if shape == "cylinder":  # and the whole fit still finds the cylinder
        assert fit is not None and abs(fit.radius - 0.05) < 0.002 and fit.count > 300


@pytest.mark.parametrize("n", [1, 2, 3, 200])
def test_view_median_is_numpys(n):
    rng = np.random.default_rng(n)
    points = rng.normal(size=(500, 3)).astype(np.float32)
    pixels = rng.choice(500, n, replace=False)
    centre = np.array([0.3, -0.2, 1.5])
    want = np.median(np.linalg.norm(points[pixels] - centre, axis=1))
    assert kernels.view_median(points, pixels, centre) == pytest.approx(want, abs=1e-12)


def _plane_box_numpy(points, normal):
    """plane_box as numpy passes (what the compiled frame coordinates replace)."""
    e1, e2 = obb._frame(normal)
    o = points.mean(0)
    D = points - o
    Q = np.column_stack([D @ e1, D @ e2])
    sample = Q if len(Q) <= 2000 else Q[np.linspace(0, len(Q) - 1, 2000).astype(int)]
    d1 = obb._rectangle_direction(sample)
    d2 = np.array([-d1[1], d1[0]])
    u, v = Q @ d1, Q @ d2
    mid = (u.max() + u.min()) / 2 * d1 + (v.max() + v.min()) / 2 * d2
    a1 = d1[0] * e1 + d1[1] * e2
    h = D @ normal
    center = o + mid[0] * e1 + mid[1] * e2 + (h.max() + h.min()) / 2 * normal
    R = np.column_stack([a1, obb.cross(normal, a1), normal])
    return center, R, np.array([np.ptp(u), np.ptp(v), np.ptp(h)])


@pytest.mark.parametrize("n", [3, 500, 5000])
def test_plane_box_is_the_numpy_one(n):
    rng = np.random.default_rng(n)
    normal = obb.cross([0.2, 0.1, 1.0], [1.0, 0.3, 0.0])
    normal /= np.linalg.norm(normal)
    e1, e2 = obb._frame(normal)
    uv = rng.uniform(-0.4, 0.4, (n, 2)) * [1.0, 0.5]
    points = 0.7 + uv[:, :1] * e1 + uv[:, 1:] * e2 + rng.normal(0, 0.002, (n, 1)) * normal
    box = obb.plane_box(points, normal)
    for got, want in zip((box.center, box.rotation, box.extent), _plane_box_numpy(points, normal),
                         strict=True):  # fmt: skip
        assert np.abs(got - want).max() < 1e-12


def test_fill_counts_the_occupied_cells():
    rng = np.random.default_rng(0)
    points = np.column_stack([rng.uniform(0, 0.3, 400), rng.uniform(0, 0.1, 400), np.zeros(400)])
    normal = np.array([0.0, 0.0, 1.0])
    p = primitives.Extracted("plane", np.arange(400), points, obb.plane_box(points, normal), 0,
                             normal=normal)  # fmt: skip
    R = p.box.rotation
    uv = (points - p.box.center) @ R[:, :2]
    shape = np.maximum(1, np.ceil(p.box.extent[:2] / 0.02)).astype(int)
    ij = np.clip(((uv + p.box.extent[:2] / 2) / 0.02).astype(int), 0, shape - 1)
    want = len(np.unique(ij[:, 0] * shape[1] + ij[:, 1])) / float(np.prod(shape))
    assert primitives.fill(p) == want


def _prim(points: np.ndarray, box: obb.Box) -> primitives.Extracted:
    return primitives.Extracted("box", np.arange(len(points)), points, box, 0)


@pytest.mark.parametrize("seed", range(8))
def test_face_contact_is_the_numpy_one(seed):
    rng = np.random.default_rng(seed)
    config = relations.RelationConfig()
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0] if seed % 2 else np.eye(3)
    table = obb.Box(np.zeros(3), R, np.array([1.0, 0.8, 0.05]))
    # an object's points on, beside or partly over the table's top face, within noise
    n = int(rng.integers(50, 2000))
    centre = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.5, 0.5), 0.025])
    local = centre + rng.uniform(-0.05, 0.05, (n, 3)) * np.array([1, 1, 0])
    local[:, 2] += rng.uniform(0, 0.1, n) * (rng.random(n) < 0.7) + rng.normal(0, 0.004, n)
    points = local @ R.T
    s, o = _prim(np.zeros((1, 3)), table), _prim(points, obb.pca_box(points))
    got = relations._face_contact(s, o, config)
    want = relations._face_contact_numpy(s, o, config)
    assert (got is None) == (want is None)
    if want is not None:
        for g, w in zip(got, want, strict=True):
            assert np.allclose(g, w, atol=1e-9)


def test_face_contact_finds_the_top_face_a_box_rests_on():
    config = relations.RelationConfig()
    table = obb.Box(np.zeros(3), np.eye(3), np.array([1.0, 0.8, 0.05]))
    rng = np.random.default_rng(0)
    cup = rng.uniform([-0.05, -0.05, 0.026], [0.05, 0.05, 0.15], (800, 3))
    got = relations._face_contact(_prim(np.zeros((1, 3)), table), _prim(cup, table), config)
    assert got is not None
    normal, point, share = got
    assert np.allclose(normal, [0, 0, 1]) and share == 1.0
    assert 0.025 < point[2] < 0.045  # the cup's points within 2 cm of the top
    beside = cup + np.array([0.55, 0, -0.1])  # next to the table, reaching below its top
    got = relations._face_contact(_prim(np.zeros((1, 3)), table), _prim(beside, table), config)
    assert got is not None and np.allclose(got[0], [1, 0, 0])  # its side face: no support


@pytest.mark.parametrize("seed", range(6))
def test_curved_refits_are_the_numpy_ones(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 3000))
    axis = ransac._unit(rng.normal(size=3))
    e1 = ransac._unit(np.cross(axis, [1.0, 0, 0]))
    e2 = np.cross(axis, e1)
    phi = rng.uniform(0, rng.uniform(0.5, 6.0), n)  # an arc of the side, or nearly all of it
    radial = np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2)
    X = 0.05 * radial + np.outer(rng.uniform(0, 0.2, n), axis) + rng.normal(0, 0.002, (n, 3))
    N = ransac._unit(radial + rng.normal(0, 0.05, (n, 3)))
    mask = rng.random(n) < 0.8
    centre, a, r, ok = kernels.cylinder_refine(X, N, mask, axis)
    c_ref, a_ref, r_ref = ransac.refine_cylinder(X[mask], N[mask], axis)
    assert ok and abs(r - r_ref) < 1e-9 and np.allclose(centre, c_ref, atol=1e-9)
    assert np.allclose(a, a_ref, atol=1e-9) or np.allclose(a, -a_ref, atol=1e-9)
    sphere = 0.07 * ransac._unit(rng.normal(size=(n, 3))) + rng.normal(0, 0.002, (n, 3))
    centre, r, ok = kernels.sphere_refine(sphere, mask)
    c_ref, r_ref = ransac.refine_sphere(sphere[mask])
    assert ok and abs(r - r_ref) < 1e-9 and np.allclose(centre, c_ref, atol=1e-9)
    assert abs(r - 0.07) < 0.01


@pytest.mark.parametrize("n", [1, 2, 3, 10, 11, 999])
def test_plane_band_is_numpys_percentile(n):
    rng = np.random.default_rng(n)
    X, normal = rng.normal(size=(n, 3)), ransac._unit(rng.normal(size=3))
    got = kernels.plane_band(X, normal, 0.3, 10.0, 90.0)
    assert np.allclose(got, np.percentile(X @ normal + 0.3, (10, 90)), atol=1e-12)


def test_plane_inliers_are_the_thresholded_residuals():
    rng = np.random.default_rng(3)
    X, N = rng.normal(0, 0.05, (5000, 3)), ransac._unit(rng.normal(size=(5000, 3)))
    normal = ransac._unit(np.array([0.1, 0.2, 1.0]))
    got = kernels.plane_inliers(X, N, normal, 0.01, 0.02, 0.5)
    res = ransac.plane_residuals(X, N, normal, 0.01)
    want = (res[0] < 0.02) & (res[1] > 0.5)
    assert 100 < want.sum() < 4900 and (got == want).all()


def test_region_spans_are_each_regions_largest_side():
    rng = np.random.default_rng(4)
    points = rng.normal(0, 1, (60, 80, 3)).astype(np.float32)
    labels = rng.integers(-1, 5, (60, 80)).astype(np.int32)
    got = kernels.region_spans(points, labels, 5)
    want = [np.ptp(points[labels == r], axis=0).max() for r in range(5)]
    assert np.allclose(got, want) and min(want) > 1.0


@pytest.mark.parametrize("seed", range(4))
def test_hypothesis_scores_are_the_thresholded_residuals(seed):
    rng = np.random.default_rng(seed)
    n = 3000
    X = rng.normal(0, 0.1, (n, 3))
    N = ransac._unit(X + rng.normal(0, 0.3, (n, 3)))  # about radial: a noisy ball
    subset = rng.integers(0, n, 500)
    centers, radii = rng.normal(0, 0.02, (8, 3)), rng.uniform(0.05, 0.2, 8)
    axes = ransac._unit(rng.normal(size=(8, 3)))
    dist, cos_min = 0.02, 0.8
    Xs, Ns = X[subset], N[subset]
    want_c = [
        int(np.count_nonzero(np.logical_and(*_below(ransac.cylinder_residuals(Xs, Ns, c, a, r),
                                                     dist, cos_min))))
        for c, a, r in zip(centers, axes, radii, strict=True)
    ]  # fmt: skip
    want_s = [
        int(np.count_nonzero(np.logical_and(*_below(ransac.sphere_residuals(Xs, Ns, c, r),
                                                     dist, cos_min))))
        for c, r in zip(centers, radii, strict=True)
    ]  # fmt: skip
    got_c = kernels.score_cylinders(X, N, subset, centers, axes, radii, dist, cos_min)
    got_s = kernels.score_spheres(X, N, subset, centers, radii, dist, cos_min)
    assert list(got_c) == want_c and list(got_s) == want_s and max(want_s) > 20
    # one hypothesis (the plane through three points), no refinement: that plane
    n0 = ransac._unit(np.cross(X[1] - X[0], X[2] - X[0]))
    found_n, d, _, found = kernels.plane_ransac(X, N, np.array([[0, 1, 2]]), subset, dist, 0.0, 0)
    assert found and abs(abs(found_n @ n0) - 1.0) < 1e-12 and abs(found_n @ X[2] + d) < 1e-12


def _below(res, dist, cos_min):
    return res[0] < dist, res[1] > cos_min


@pytest.mark.parametrize("seed", range(8))
def test_normal_arc_and_spread_are_the_numpy_ones(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(0, 5000)) if seed else 1
    axis = ransac._unit(rng.normal(size=3)) if seed % 3 else np.array([1.0, 0, 0])
    arc = rng.uniform(0.1, 2 * np.pi)  # normals over an arc of the axis, noisy
    e1 = ransac._unit(np.cross(axis, rng.normal(size=3)))
    phi = rng.uniform(0, arc, n)
    N = np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), np.cross(axis, e1))
    N = ransac._unit(N + rng.normal(0, 0.02, (n, 3)))
    got = ransac.cylinder_arc(N, axis)
    assert got == pytest.approx(ransac.cylinder_arc_numpy(N, axis), abs=1e-9)
    spread = ransac.sphere_spread(N)
    assert spread == pytest.approx(ransac.sphere_spread_numpy(N), abs=1e-7)
    if n > 1000:
        assert abs(got - np.degrees(arc)) < 10
