"""Spatio-temporal fusion of geometric primitives (Algorithm 2) and support-graph combination
(thesis 3.3, 3.3.1, Table 3.1).

For a new view's primitives Ψ^{t+1} and the memory Ψ^{1,t}:

1. frustum culling: only memory primitives in the camera's view take part;
2. for each pair (ψ old, φ new) whose OBBs intersect and whose models agree
   (CompareModelParameters), with Inlier(a, b) = |P_a ∩ OBB(b)| / |P_a| (Eq. 3.8):
   - both cover each other (> λ_o): the same primitive seen again → merged into ψ (modified);
   - φ ⊂ ψ (Inlier(φ, ψ) ≥ 0.95), or Inlier(φ, ψ) > λ_o and Inlier(ψ, φ) < λ_p: φ is
     covered by the larger ψ → φ dropped (its points join ψ);
   - ψ ⊂ φ, or Inlier(ψ, φ) > λ_o and Inlier(φ, ψ) < λ_p: ψ is covered by the larger φ →
     ψ removed, φ takes its place (and its support edges);
   - coplanar pieces of one plane (both below λ_o): joined into one plane (modified);
   - otherwise (partial overlap, λ_p ≤ coverage): both survive;
   one solid seen as two kinds (a thin leg as a box and as a cylinder) follows the same
   coverage rules, the memory's kind kept;
3. Ψ^{1,t+1} = surviving memory ∪ surviving new.

Support graphs combine (Table 3.1) by ``sg``: each view's primitives are fused as above and
its edges, mapped onto memory ids, count into occ(e). ``pc`` and ``pc+sg`` fuse observations
of the registered cloud of the whole roi (every view so far merged in the map, which the
scene memory publishes for perception to re-extract): ``pc`` takes the scene model as
extracted from it, G_s^t, replacing the memory's primitives and edges (occ(e) = 1); ``pc+sg``
fuses it into the memory like a view (all of the memory takes part: the cloud saw the whole
roi) and counts its edges into occ(e).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from schemas import (
    BoxModel,
    CylinderModel,
    Obb,
    PlaneModel,
    Primitive,
    SceneModel,
    SceneObservation,
    SpatialEdge,
    SphereModel,
    SupportEdge,
)
from services.common import sat
from services.common.sat import boxes_overlap, overlap, pairs_overlap
from services.scene_memory.evidence import ViewDepth, depth_sigma
from services.scene_memory.stability import (
    BELOW_EVIDENCE,
    ROUND,
    Body,
    StabilityConfig,
    Touches,
    level_area,
    settle,
)

MAX_POINTS = 6000  # points a memory primitive keeps (voxel-downsampled)
BOX_GROWTH = 0.01  # m: points this far beyond a box's face make it grow
UP = np.array([0.0, 0.0, 1.0])


@dataclass
class FusionConfig:
    lambda_o: float = 0.7
    lambda_p: float = 0.3
    contained: float = 0.95  # Inlier(φ, ψ) from which φ ⊂ ψ (Algorithm 2: φ is dropped)
    face_distance: float = 0.02  # a plane this close to a box's surface is one of its faces
    surface_tolerance: float = 0.01  # a part of a solid lies this close to its surface
    obb_margin: float = 0.01  # Eq. 3.8's OBB containment, allowing for depth noise
    voxel: float = 0.01  # downsampling of merged inlier clouds
    plane_angle_deg: float = 5.0  # CompareModelParameters tolerances
    plane_offset: float = 0.01
    #: ... or, farther from the camera, this many σ(z) of a structured-light sensor's depth
    #: noise at the plane's distance (σ(z) = 0.0012 + 0.0019·(z − 0.4)², Nguyen et al. 2012:
    #: 9.6 mm at 2.5 m, where Kinect v1's depth comes in 18 mm steps): a wall seen from 2.5 m
    #: in two views sits 1-2 cm apart; 0: ``plane_offset`` at any distance
    plane_offset_sigmas: float = 2.0
    axis_angle_deg: float = 10.0
    radius: float = 0.015
    center: float = 0.03
    extent: float = 0.03
    epsilon: float = 0.05  # spatial graph ε (Eq. 3.6)
    changed: float = 0.01  # a merge that moves or grows a box by less is no modification
    large_plane_area: float = 0.3  # m²: planes this large join coplanar pieces ...
    plane_gap: float = 0.25  # ... up to this far apart
    floor_band: float = 0.04  # level planes this close to the lowest one are the floor ...
    floor_max: float = 0.3  # ... when it lies this low (the world's ground is z = 0)
    ground_area: float = 0.2  # level surfaces this large count as ground (stability)
    #: ... and so do upright surfaces this tall and wide (m: a wall, a cabinet's front): the
    #: room's structure, whose foot is often out of sight. A flat thing against one (a
    #: poster, a shelf board, a brochure leaning on it) is held by it; an object is not
    structure_height: float = 0.5
    structure_width: float = 0.3
    attached: float = 0.02  # m: a plane this close to a structure is against it
    rest_tolerance: float = 0.03  # a supported primitive reaches this far below its supporter
    #: m: of two supporters of one primitive where the lower supports the upper (a table, a
    #: tray on it), the lower is dropped when the primitive's bottom is this much nearer the
    #: upper's top: a cup on a tray rests on the tray (the table holds it through the tray)
    nearer_top: float = 0.01
    #: m: what does not rise this far above a ground surface's top does not lie on it: the
    #: surface's own pieces (a table top fused in two), its edge's faces (``support``)
    level_with: float = 0.01
    #: m: what rests on a raised ground surface (a table top, a board; not the floor, seen up
    #: to the walls) has its centre over it (its weight on it), within this margin: a
    #: shelf's side panel, its top beside the board and above it, does not
    over_margin: float = 0.005
    #: negative evidence (``evidence.py``): a primitive that this many views in a row saw
    #: through (more than ``through_share`` of its points with evidence, at least
    #: ``through_points`` of them) is gone from the scene; 0: never
    decay_views: int = 2
    through_share: float = 0.5
    through_points: int = 10
    through_margin: float = 0.02  # m beyond the depth noise (registration, a surface's thickness)
    through_cell: int = 16  # px: the grid a view's surfaces are compared in
    #: a primitive of one view that this many later views saw the surface of without
    #: matching it goes (0: never)
    unconfirmed_views: int = 3
    #: a primitive with no support found is *unstable* once this many views saw through the
    #: space 5-15 cm under its base (nothing there holds it); until then its support is
    #: *unresolved*: hidden from every view so far, the thesis's "incomplete scene model"
    #: (3.2.2). 0: every primitive with no support is unstable (the thesis's rule)
    below_views: int = 1
    mode: str = "sg"  # pc | sg | pc+sg


@dataclass
class MemoryPrimitive:
    id: int
    primitive: Primitive  # model, OBB, colour as last fused (id field = memory id)
    points: np.ndarray  # (n, 3) float32 fused inliers
    views: int = 1
    seen_through: int = 0  # views in a row that saw through it since it was last matched
    unconfirmed: int = 0  # views that saw its surface and matched nothing to it (views == 1)
    below_free: int = 0  # views that saw through the space under its base (stability.py)
    round_votes: int = 0  # views that saw it as a cylinder minus those that saw a sphere


@dataclass
class Update:
    added: int = 0
    modified: int = 0
    removed: int = 0
    dropped: int = 0  # new primitives that merged several the memory holds apart
    decayed: int = 0  # of the removed: seen through by ``decay_views`` views in a row
    mapping: dict[int, int] = field(default_factory=dict)  # observation id → memory id


# -- geometry helpers --------------------------------------------------------------------------


def _direct(
    edges: dict[tuple[int, int], int], bodies: dict[int, Body], nearer: float
) -> dict[tuple[int, int], int]:
    """``edges`` without a → b where b also rests on an m that a holds and b's bottom lies
    ``nearer`` closer to m's top than to a's (the tray between the table and the cup)."""
    held: dict[int, list[int]] = {}
    for a, b in edges:
        held.setdefault(b, []).append(a)
    out = {}
    for (a, b), n in edges.items():
        bottom = bodies[b].bottom
        through = any(
            (a, m) in edges and abs(bottom - bodies[a].top) - abs(bottom - bodies[m].top) > nearer
            for m in held[b]
            if m != a
        )
        if not through:
            out[a, b] = n
    return out


@njit(cache=True, nogil=True)
def _count_in_box(points, centre, R, half):
    """How many of ``points`` lie in the box (centre, axes as R's columns, half extents)."""
    n = 0
    for i in range(points.shape[0]):
        dx = points[i, 0] - centre[0]
        dy = points[i, 1] - centre[1]
        dz = points[i, 2] - centre[2]
        inside = True
        for a in range(3):
            if abs(dx * R[0, a] + dy * R[1, a] + dz * R[2, a]) > half[a]:
                inside = False
                break
        n += inside
    return n


def inlier(points: np.ndarray, obb: Obb, margin: float, boxes: _Boxes | None = None) -> float:
    """Inlier(a, b) = |P_a ∩ OBB(b)| / |P_a| (Eq. 3.8). (Compiled: the memory's primitives keep
    up to 6000 points, and a kitchen observation asks this hundreds of times.) ``boxes``: the
    step's converted boxes, where ``obb`` is taken from (else converted here). Float32 points
    are counted as they are (each coordinate widened exactly, as a float64 copy would be)."""
    if not len(points):
        return 0.0
    if points.dtype not in (np.float32, np.float64) or not points.flags.c_contiguous:
        points = np.ascontiguousarray(points, np.float64)
    if boxes is not None:
        _, R, c, h, _, _ = boxes._of(obb)
    else:
        c = np.array(obb.center, np.float64)
        R = np.array(obb.rotation, np.float64, order="C")
        h = np.asarray(obb.extent, np.float64) / 2
    return _count_in_box(points, c, R, h + margin) / len(points)


def _inside(points: np.ndarray, obb: Obb, margin: float) -> np.ndarray:
    """Which of ``points`` lie in ``obb`` grown by ``margin`` (a mask; ``inlier`` counts)."""
    local = (np.asarray(points, np.float64) - obb.center) @ np.asarray(obb.rotation, np.float64)
    return np.all(np.abs(local) <= np.asarray(obb.extent) / 2 + margin, axis=1)


def obbs_intersect(a: Obb, b: Obb, epsilon: float = 0.0) -> bool:
    """Separating-axis test of two OBBs, each grown by ``epsilon``."""
    return boxes_overlap(a.rotation, a.center, a.extent, b.rotation, b.center, b.extent, epsilon)


class _Boxes:
    """The OBBs of one fusion step as the separating-axis kernel takes them, each converted
    once (an observation against a 200-primitive kitchen model asks ~2000 pairs, and
    converting both boxes per pair cost more than the test), and a bounding-sphere test first:
    boxes whose spheres (grown like the boxes) are apart cannot overlap, and most pairs are
    such. The same answers as ``obbs_intersect``."""

    def __init__(self) -> None:
        # id(obb) → (obb, R, centre, half extents, centre as floats, half extents as floats);
        # the obb is kept so that its id is not reused while the entry lives
        self._cache: dict[int, tuple] = {}

    def _of(self, obb: Obb) -> tuple:
        g = self._cache.get(id(obb))
        if g is None or g[0] is not obb:
            c = np.array(obb.center, np.float64)
            h = np.asarray(obb.extent, np.float64) / 2
            g = (obb, np.array(obb.rotation, np.float64, order="C"), c, h,
                 tuple(c.tolist()), tuple(h.tolist()))  # fmt: skip
            self._cache[id(obb)] = g
        return g

    def intersect(self, a: Obb, b: Obb, epsilon: float = 0.0) -> bool:
        """``obbs_intersect(a, b, epsilon)``."""
        _, Ra, ca, ha, (ax, ay, az), (hax, hay, haz) = self._of(a)
        _, Rb, cb, hb, (bx, by, bz), (hbx, hby, hbz) = self._of(b)
        reach = math.hypot(hax + epsilon, hay + epsilon, haz + epsilon) + math.hypot(
            hbx + epsilon, hby + epsilon, hbz + epsilon
        )
        if (ax - bx) ** 2 + (ay - by) ** 2 + (az - bz) ** 2 > reach * reach * (1 + 1e-9):
            return False
        return bool(overlap(Ra, ca, ha + epsilon, Rb, cb, hb + epsilon))


class _Shapes:
    """``Fusion._level_area`` and ``_z_range`` of each OBB asked, computed once while the
    scene model is built (its support edges and stability ask them per edge, hundreds of
    times in a kitchen)."""

    def __init__(self) -> None:
        self._level: dict[int, tuple[Obb, float]] = {}
        self._z: dict[int, tuple[Obb, tuple[float, float]]] = {}

    def level_area(self, p: Primitive) -> float:
        hit = self._level.get(id(p.obb))
        if hit is None or hit[0] is not p.obb:
            hit = self._level[id(p.obb)] = (p.obb, Fusion._level_area(p))
        return hit[1]

    def z_range(self, obb: Obb) -> tuple[float, float]:
        hit = self._z.get(id(obb))
        if hit is None or hit[0] is not obb:
            hit = self._z[id(obb)] = (obb, _z_range(obb))
        return hit[1]


class _Near:
    """Which of a step's memory primitives lie near enough to a box to overlap it at
    ``reach``, all at once (bounding spheres grown by ``reach``): Algorithm 2's pair loop then
    tests only those (a kitchen view's dozen primitives against 200 visible ones)."""

    def __init__(self, prims: list[MemoryPrimitive], reach: float) -> None:
        self.reach = reach
        self.row = {m.id: j for j, m in enumerate(prims)}
        self.centres = np.zeros((len(prims), 3))
        self.radii = np.zeros(len(prims))
        for m in prims:
            self.moved(m)

    def moved(self, m: MemoryPrimitive) -> None:
        """``m``'s box changed (a merge refitted it)."""
        j = self.row.get(m.id)
        if j is not None:
            obb = m.primitive.obb
            self.centres[j] = obb.center
            self.radii[j] = np.linalg.norm(np.asarray(obb.extent) / 2 + self.reach)

    def __call__(self, obb: Obb) -> list[bool]:
        r = np.linalg.norm(np.asarray(obb.extent) / 2 + self.reach)
        d2 = ((self.centres - obb.center) ** 2).sum(axis=1)
        return (d2 <= (self.radii + r) ** 2 * (1 + 1e-9)).tolist()


#: the corners and the centre of a unit box, in its own axes (in_frustum's test points)
_SIGNS = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)] + [[0, 0, 0]])


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(float(a @ b))))))


def _on_floor(p: Primitive, floor: float, c: FusionConfig) -> bool:
    """A level plane at the height of the lowest level plane."""
    m = p.model
    if m.kind != "plane" or abs(m.normal[2]) < np.cos(np.radians(10)):
        return False
    return abs(-m.d / m.normal[2] - floor) < c.floor_band


def _large_plane(a: Primitive, b: Primitive, c: FusionConfig) -> bool:
    if a.model.kind != "plane" or b.model.kind != "plane":
        return False
    area = max(a.obb.extent[0] * a.obb.extent[1], b.obb.extent[0] * b.obb.extent[1])
    return area >= c.large_plane_area


SOLIDS = {"box", "cylinder", "sphere"}


def compare_models(a: Primitive, b: Primitive, c: FusionConfig, distance: float = 0.0) -> bool:
    """CompareModelParameters: same kind and parameters within tolerance (boxes: axes).
    ``distance``: how far from its camera ``a`` was seen (m): planes seen far agree within
    the depth noise there (``plane_offset_sigmas``)."""
    ma, mb = a.model, b.model
    if ma.kind != mb.kind:
        return False
    if ma.kind == "plane":
        if _angle(ma.normal, mb.normal) > c.plane_angle_deg:
            return False
        tolerance = max(c.plane_offset, c.plane_offset_sigmas * depth_sigma(distance))
        return abs(float(mb.normal @ a.obb.center) + mb.d) < tolerance
    if ma.kind == "cylinder":
        if _angle(ma.axis, mb.axis) > c.axis_angle_deg or abs(ma.radius - mb.radius) > c.radius:
            return False
        v = ma.center - mb.center
        return float(np.linalg.norm(v - (v @ mb.axis) * mb.axis)) < c.center
    if ma.kind == "sphere":
        return (
            abs(ma.radius - mb.radius) < c.radius
            and np.linalg.norm(ma.center - mb.center) < c.center
        )
    # boxes: the same axes. Not the same size: a box seen from one side is cut short where
    # the view ends, and a later view sees more of it; Eq. 3.8's coverage tells the rest
    R = np.abs(ma.rotation.T @ mb.rotation)
    return bool(np.all(R.max(axis=1) >= np.cos(np.radians(c.axis_angle_deg))))


def round_pair(a: Primitive, b: Primitive, c: FusionConfig) -> bool:
    """A sphere and a cylinder of about one radius, the sphere's centre on the cylinder's
    axis within its length: one round object that one view fitted as a ball and another as a
    can (a bellied cup seen from the side, then from above)."""
    if {a.model.kind, b.model.kind} != ROUND:
        return False
    ball, can = (a.model, b.model) if a.model.kind == "sphere" else (b.model, a.model)
    if abs(ball.radius - can.radius) > c.radius:
        return False
    v = ball.center - can.center
    along = float(v @ can.axis)
    off_axis = float(np.linalg.norm(v - along * can.axis))
    return off_axis < c.center and abs(along) <= can.height / 2 + c.center


def _round_vote(kind: str) -> int:
    return {"cylinder": 1, "sphere": -1}.get(kind, 0)


def voxel_keys(points: np.ndarray, voxel: float) -> np.ndarray:
    """One int64 per voxel (21 bits per axis, ±10 km at 1 cm)."""
    k = np.floor(points / voxel).astype(np.int64) + (1 << 20)
    return (k[:, 0] << 42) | (k[:, 1] << 21) | k[:, 2]


@njit(cache=True, nogil=True)
def _slot(k, mask):
    """A key's first slot in a hash table of ``mask + 1`` slots (splitmix64's finaliser: the
    keys' axes sit in separate bit ranges)."""
    z = np.uint64(k)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return np.int64(z ^ (z >> np.uint64(31))) & mask


@njit(cache=True, nogil=True)
def first_of_each(keys: np.ndarray) -> np.ndarray:
    """Indices of the first occurrence of each key, in increasing order (``np.unique``'s
    first indices, sorted) by a hash table instead of a sort: a memory primitive's merge
    deduplicates its 6000 points and the view's again at every observation."""
    n = keys.shape[0]
    size = 16
    while size < 2 * n:
        size <<= 1
    mask = size - 1
    table = np.full(size, -1, np.int64)
    keep = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        k = keys[i]
        h = _slot(k, mask)
        while True:
            j = table[h]
            if j < 0:
                table[h] = i
                keep[m] = i
                m += 1
                break
            if keys[j] == k:
                break
            h = (h + 1) & mask
    return keep[:m]


@njit(cache=True, nogil=True)
def _first_per_voxel(a, b, voxel, single):
    """``first_of_each(voxel_keys(concatenate([a, b]), voxel))`` in one pass over both point
    sets, without making the concatenation or its keys: the indices are into it. ``single``:
    both are float32, and so is their concatenation, whose keys numpy divides in float32
    (else in float64)."""
    na, nb = a.shape[0], b.shape[0]
    v32 = np.float32(voxel)
    keys = np.empty(na + nb, np.int64)
    offset = np.int64(1 << 20)
    for i in range(na + nb):
        if i < na:
            x, y, z = np.float64(a[i, 0]), np.float64(a[i, 1]), np.float64(a[i, 2])
        else:
            x, y, z = np.float64(b[i - na, 0]), np.float64(b[i - na, 1]), np.float64(b[i - na, 2])
        if single:
            x = np.float64(np.float32(np.float32(x) / v32))
            y = np.float64(np.float32(np.float32(y) / v32))
            z = np.float64(np.float32(np.float32(z) / v32))
        else:
            x, y, z = x / voxel, y / voxel, z / voxel
        kx = np.int64(np.floor(x)) + offset
        ky = np.int64(np.floor(y)) + offset
        kz = np.int64(np.floor(z)) + offset
        keys[i] = (kx << 42) | (ky << 21) | kz
    return first_of_each(keys)


@njit(cache=True, nogil=True)
def _gather32(a, b, index):
    """``concatenate([a, b])[index].astype(float32)`` without the concatenation."""
    na = a.shape[0]
    out = np.empty((index.shape[0], 3), np.float32)
    for r in range(index.shape[0]):
        i = index[r]
        for c in range(3):
            out[r, c] = np.float32(a[i, c]) if i < na else np.float32(b[i - na, c])
    return out


_NO_POINTS = np.zeros((0, 3), np.float64)


def downsample(
    points: np.ndarray, voxel: float, cap: int = MAX_POINTS, more: np.ndarray | None = None
) -> np.ndarray:
    """One point per voxel (the first), at most ``cap`` (evenly spread), as float32; of
    ``points`` followed by ``more`` (a memory primitive's points and a view's: the same as of
    their concatenation, which is not made)."""
    a = np.ascontiguousarray(points)
    b = _NO_POINTS if more is None else np.ascontiguousarray(more)
    if a.dtype not in (np.float32, np.float64) or b.dtype not in (np.float32, np.float64):
        a, b = a.astype(np.float64), b.astype(np.float64)
    single = a.dtype == np.float32 and (more is None or b.dtype == np.float32)
    first = _first_per_voxel(a, b, float(voxel), single)
    if len(first) > cap:
        first = first[np.linspace(0, len(first) - 1, cap).astype(int)]
    return _gather32(a, b, first)


@njit(cache=True, nogil=True)
def _column_range(a):
    """``a.min(0), a.max(0)`` of an (n, 3) array (numpy's reduction down the columns of a
    plane's 6000 points cost 0.3 ms a refit, ten times the product before it)."""
    lo = a[0].copy()
    hi = a[0].copy()
    for i in range(1, a.shape[0]):
        for c in range(3):
            x = a[i, c]
            if x < lo[c]:
                lo[c] = x
            elif x > hi[c]:
                hi[c] = x
    return lo, hi


def _frame_obb(points: np.ndarray, R: np.ndarray) -> Obb:
    local = points @ R
    lo, hi = _column_range(local) if len(local) else (local.min(0), local.max(0))
    return Obb(center=R @ ((lo + hi) / 2), rotation=R, extent=hi - lo)


def _circle(q: np.ndarray, r0: float) -> tuple[np.ndarray, float]:
    """Geometric circle fit (Gauss-Newton from the origin and r0); falls back to them."""
    c, r = np.zeros(2), r0
    for _ in range(10):
        d = q - c
        dist = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        J = np.column_stack([-d / dist[:, None], -np.ones(len(q))])
        try:
            step = np.linalg.solve(J.T @ J, J.T @ (r - dist))
        except np.linalg.LinAlgError:
            return np.zeros(2), r0
        c, r = c + step[:2], r + step[2]
        if np.abs(step).max() < 1e-6:
            break
    if not (0 < r < 4 * r0) or np.linalg.norm(c) > 2 * r0:
        return np.zeros(2), r0
    return c, float(r)


def refit(base: Primitive, points: np.ndarray, pid: int) -> Primitive:
    """``base``'s primitive refitted to a merged point set (its kind and axes kept)."""
    m = base.model
    R = base.obb.rotation
    if m.kind == "plane":
        c = points.mean(0)
        _, _, vt = np.linalg.svd(points - c, full_matrices=False)
        n = vt[2] if vt[2] @ m.normal >= 0 else -vt[2]
        a1 = R[:, 0] - (R[:, 0] @ n) * n
        a1 /= np.linalg.norm(a1)
        R = np.column_stack([a1, np.cross(n, a1), n])
        model = PlaneModel(normal=n, d=float(-n @ c))
    elif m.kind == "cylinder":
        # the axis is kept; centre and radius from a circle fit of all the points seen so far
        e1, e2 = R[:, 0], R[:, 1]
        q = np.column_stack([(points - m.center) @ e1, (points - m.center) @ e2])
        c2, radius = _circle(q, m.radius)
        t = (points - m.center) @ m.axis
        center = m.center + c2[0] * e1 + c2[1] * e2 + m.axis * (t.max() + t.min()) / 2
        model = CylinderModel(center=center, axis=m.axis, radius=radius, height=float(np.ptp(t)))
        obb = Obb(center=center, rotation=R, extent=np.array([2 * radius, 2 * radius, np.ptp(t)]))
        return base.model_copy(
            update={"id": pid, "model": model, "obb": obb, "inlier_count": len(points)}
        )
    elif m.kind == "sphere":
        # centre and radius from all the points seen so far (algebraic fit: |p|² = 2c·p + k)
        A = np.column_stack([2 * points, np.ones(len(points))])
        sol, *_ = np.linalg.lstsq(A, (points**2).sum(1), rcond=None)
        center, k = sol[:3], sol[3]
        r2 = k + center @ center
        if r2 > 0 and abs(np.sqrt(r2) - m.radius) < 0.5 * m.radius:
            model = SphereModel(center=center, radius=float(np.sqrt(r2)))
            obb = Obb(center=center, rotation=R, extent=np.full(3, 2 * model.radius))
            return base.model_copy(
                update={"id": pid, "model": model, "obb": obb, "inlier_count": len(points)}
            )
        model = m
    else:  # a box grows where a share of its points lie clearly beyond a face (a part of it
        # seen for the first time), and keeps its faces where they were fitted otherwise:
        # the noise of the points would inflate it a little with every view
        R = m.rotation
        local = points @ R
        c = m.center @ R
        lo, hi = c - m.extent / 2, c + m.extent / 2
        p_lo, p_hi = np.percentile(local, 2, axis=0), np.percentile(local, 98, axis=0)
        lo = np.where(p_lo < lo - BOX_GROWTH, p_lo, lo)
        hi = np.where(p_hi > hi + BOX_GROWTH, p_hi, hi)
        model = BoxModel(center=R @ ((lo + hi) / 2), rotation=R, extent=hi - lo)
        obb = Obb(center=model.center, rotation=R, extent=model.extent)
        return base.model_copy(
            update={"id": pid, "model": model, "obb": obb, "inlier_count": len(points)}
        )
    obb = _frame_obb(points, R) if m.kind == "plane" else base.obb
    return base.model_copy(
        update={"id": pid, "model": model, "obb": obb, "inlier_count": len(points)}
    )


def on_surface(p: Primitive, points: np.ndarray, tolerance: float) -> bool:
    """Do the points lie on ``p``'s surface (median distance within ``tolerance``)? A part
    of a box seen again does; a tray lying on the table box, 2 cm above it, does not."""
    return len(points) > 0 and float(np.median(p.model.distance(points))) <= tolerance


def _z_range(obb: Obb) -> tuple[float, float]:
    """Lowest and highest z of an OBB's corners."""
    reach = float(np.abs(obb.rotation[2]) @ (obb.extent / 2))
    return float(obb.center[2]) - reach, float(obb.center[2]) + reach


def _over(p: Primitive, g: Primitive, tolerance: float) -> bool:
    """Is ``p``'s centre inside the level surface ``g``'s footprint (grown by ``tolerance``)?"""
    local = (p.obb.center - g.obb.center) @ g.obb.rotation
    k = int(np.argmax(np.abs(g.obb.rotation[2])))  # the surface's vertical axis
    others = [m for m in range(3) if m != k]
    return bool(np.all(np.abs(local[others]) <= g.obb.extent[others] / 2 + tolerance))


def _under(p: Primitive, grounds: list[Primitive], tolerance: float, z_range=_z_range) -> bool:
    """Is ``p`` part of the furniture below a ground surface: its top not above the
    surface's (plus ``tolerance``), its centre inside the surface's footprint?"""
    top = z_range(p.obb)[1]
    return any(
        g is not p and top <= z_range(g.obb)[1] + tolerance and _over(p, g, tolerance)
        for g in grounds
    )


def in_frustum(obb: Obb, obs: SceneObservation) -> bool:
    """Is the OBB's centre (or a corner) inside the camera's field of view and range?"""
    K, T = obs.intrinsics, obs.T_world_camera
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)] + [[0, 0, 0]])
    pts = obb.center + (signs * obb.extent / 2) @ obb.rotation.T
    cam = (pts - T[:3, 3]) @ T[:3, :3]
    z = cam[:, 2]
    ok = (z > 0.05) & (z < obs.depth_max + 0.5)
    u = K.fx * cam[:, 0] / np.where(ok, z, 1) + K.cx
    v = K.fy * cam[:, 1] / np.where(ok, z, 1) + K.cy
    return bool(np.any(ok & (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)))


def in_frustum_all(obbs: list[Obb], obs: SceneObservation) -> np.ndarray:
    """``in_frustum`` of every box at once (bool per box)."""
    if not obbs:
        return np.zeros(0, bool)
    K, T = obs.intrinsics, obs.T_world_camera
    centres = np.array([o.center for o in obbs], np.float64)
    rotations = np.array([o.rotation for o in obbs], np.float64)
    extents = np.array([o.extent for o in obbs], np.float64)
    local = _SIGNS[None] * extents[:, None] / 2  # (n, 9, 3)
    pts = centres[:, None] + np.einsum("nkj,nij->nki", local, rotations)
    cam = (pts - T[:3, 3]) @ T[:3, :3]
    z = cam[..., 2]
    ok = (z > 0.05) & (z < obs.depth_max + 0.5)
    u = K.fx * cam[..., 0] / np.where(ok, z, 1) + K.cx
    v = K.fy * cam[..., 1] / np.where(ok, z, 1) + K.cy
    return np.any(ok & (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height), axis=1)


# -- the memory ---------------------------------------------------------------------------------


class Fusion:
    """The fused scene: primitives with their points, support edges with occ(e)."""

    def __init__(self, config: FusionConfig | None = None) -> None:
        self.config = config or FusionConfig()
        self.prims: dict[int, MemoryPrimitive] = {}
        self.occ: dict[tuple[int, int], int] = {}
        self.next_id = 0
        self.n_views = 0
        self.version = 0
        self.last = Update()
        self._boxes = _Boxes()  # the boxes of the step under way (cleared at each update)
        # memory id → (primitive, points, its message in the last scene model built)
        self._messages: dict[int, tuple[Primitive, np.ndarray, Primitive]] = {}
        self._edge_messages: dict[tuple[int, int], SpatialEdge] = {}  # … and its spatial edges
        self._bodies: dict[int, Body] = {}  # … and as stability sees it
        self._touches: Touches = {}  # … and which touch which from below
        #: (plane, structure) → (their primitives then, whether the plane is against it)
        self._against: dict[tuple[int, int], tuple[Primitive, Primitive, bool]] = {}
        #: of the last model's stable primitives, those stability found resting (rule, on)
        self.settled: dict[int, tuple[str, int | None]] = {}
        self.unresolved: list[int] = []  # … and of its unsupported ones, those not seen under

    #: caches, rebuilt as needed: never in a snapshot
    TRANSIENT = ("_boxes", "_messages", "_edge_messages", "_bodies", "_touches", "_against")

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k not in self.TRANSIENT}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._boxes, self._messages, self._edge_messages = _Boxes(), {}, {}
        self._bodies, self._touches, self._against = {}, {}, {}

    def _new_id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def _merge_into(self, mem: MemoryPrimitive, points: np.ndarray) -> bool:
        """Merge points into a memory primitive; True when that changed it (its box moved or
        grew by more than ``changed``): a re-observation that adds nothing is no change."""
        merged = downsample(mem.points, self.config.voxel, more=points)
        before = mem.primitive.obb
        mem.primitive = refit(mem.primitive, merged.astype(np.float64), mem.id)
        mem.points = merged
        mem.views += 1
        after = mem.primitive.obb
        moved = np.linalg.norm(after.center - before.center)
        grown = np.abs(np.sort(after.extent) - np.sort(before.extent)).max()
        return bool(max(moved, grown) > self.config.changed)

    def update(self, obs: SceneObservation, whole: bool = False) -> Update:
        """Fuse one view (Algorithm 2), then combine its support graph. ``whole``: the
        observation is of the registered cloud of the whole roi, not of one camera's view:
        every memory primitive takes part (no frustum culling), and in ``pc`` mode it replaces
        the memory (Table 3.1: the graph extracted from the registered cloud is the model)."""
        c = self.config
        result = Update()
        self._boxes = boxes = _Boxes()
        if c.mode == "pc" and whole:
            result.removed = len(self.prims)
            self.prims, self.occ = {}, {}
        if whole:
            visible = list(self.prims.values())
        else:
            prims = list(self.prims.values())
            seen = in_frustum_all([m.primitive.obb for m in prims], obs)
            visible = [m for m, v in zip(prims, seen.tolist(), strict=True) if v]
        floor = self._floor_height(obs)
        if floor is not None:  # every floor piece takes part, seen now or not
            taking_part = {m.id for m in visible}
            visible += [
                m
                for m in self.prims.values()
                if m.id not in taking_part and _on_floor(m.primitive, floor, c)
            ]
        near_of = _Near(visible, max(c.plane_gap, c.obb_margin))
        eye = np.asarray(obs.T_world_camera, float)[:3, 3]
        for phi in obs.primitives:
            pts = phi.inliers.astype(np.float64)
            outcome, target = "add", None
            best = 0.0
            if phi.model.kind in SOLIDS and self._spans_objects(phi, visible, points=pts):
                result.dropped += 1  # one solid around several the memory tells apart: a
                continue  # segment that merged touching objects, not a better view of one
            phi_on_floor = floor is not None and _on_floor(phi, floor, c)
            near = near_of(phi.obb)
            distance = 0.0 if whole else float(np.linalg.norm(phi.obb.center - eye))
            pieces: list[MemoryPrimitive] = []  # memory planes φ is a piece of the same plane as
            for psi, close in zip(visible, near, strict=True):
                if psi.id not in self.prims:
                    continue
                if phi_on_floor and _on_floor(psi.primitive, floor, c):
                    outcome, target, best = "same", psi, 1.0  # the floor is one plane
                    break
                if not close:  # too far apart to overlap at any reach
                    continue
                # pieces of a large plane join across small gaps
                reach = c.plane_gap if _large_plane(phi, psi.primitive, c) else c.obb_margin
                if not boxes.intersect(psi.primitive.obb, phi.obb, reach):
                    continue
                kinds = {phi.model.kind, psi.primitive.model.kind}
                if "plane" in kinds and len(kinds & SOLIDS) == 1:
                    # a face seen alone (a box's side, a cylinder's cap), and its solid
                    in_new = inlier(pts, psi.primitive.obb, c.obb_margin, boxes)
                    in_old = inlier(psi.points, phi.obb, c.obb_margin, boxes)
                    tol = c.surface_tolerance
                    if (
                        phi.model.kind == "plane"
                        and in_new > c.lambda_o
                        and on_surface(psi.primitive, pts, tol)
                    ):
                        decision = "covered"
                    elif (
                        psi.primitive.model.kind == "plane"
                        and in_old > c.lambda_o
                        and on_surface(phi, psi.points, tol)
                    ):
                        decision = "replace"
                    else:
                        continue
                    if outcome == "add" or max(in_new, in_old) > best:
                        outcome, target, best = decision, psi, max(in_new, in_old)
                    continue
                solids = kinds <= SOLIDS
                if not solids and not compare_models(phi, psi.primitive, c, distance):
                    continue
                in_new = inlier(pts, psi.primitive.obb, c.obb_margin, boxes)
                in_old = inlier(psi.points, phi.obb, c.obb_margin, boxes)
                # a cylinder or sphere of the same parameters overlapping it is it (a box's
                # extent is no such parameter: a part seen is smaller than the whole)
                same_kind = phi.model.kind == psi.primitive.model.kind != "box"
                same_model = (
                    (same_kind and compare_models(phi, psi.primitive, c, distance))
                    or round_pair(phi, psi.primitive, c)
                ) and max(in_new, in_old) > c.lambda_p
                if solids and max(in_new, in_old) <= c.lambda_o and not same_model:
                    continue  # two solids are one only when one covers the other
                # solids are one only where the points of one lie on the other's surface (a
                # tray on the table box lies inside its OBB's margin, 2 cm above its top)
                on_old = not solids or on_surface(psi.primitive, pts, c.surface_tolerance)
                on_new = not solids or on_surface(phi, psi.points, c.surface_tolerance)
                if same_model or (
                    in_new > c.lambda_o and in_old > c.lambda_o and (on_old or on_new)
                ):
                    decision = "same"
                elif on_old and (
                    in_new >= c.contained or (in_new > c.lambda_o and in_old < c.lambda_p)
                ):
                    decision = "covered"  # φ ⊂ ψ (Algorithm 2's first test), or mostly
                elif on_new and (
                    in_old >= c.contained or (in_old > c.lambda_o and in_new < c.lambda_p)
                ):
                    decision = "replace"
                elif phi.model.kind == "plane" and max(in_new, in_old) < c.lambda_o:
                    decision = "same"  # a piece of the same plane
                else:
                    continue  # partial overlap: both survive
                score = max(in_new, in_old)
                if phi.model.kind == psi.primitive.model.kind == "plane":
                    pieces.append(psi)
                if outcome == "add" or score > best:
                    outcome, target, best = decision, psi, score
            if outcome in ("same", "covered"):
                if target.primitive.model.kind in SOLIDS:
                    pts = self._not_annexed(target, pts, visible)
                if self._merge_into(target, pts) and outcome == "same":
                    result.modified += 1
                self._vote_round(target, phi)
                result.removed += self._join_pieces(target, pieces, distance, result)
                near_of.moved(target)
                result.mapping[phi.id] = target.id
                continue
            mid = self._new_id()
            mem = MemoryPrimitive(mid, phi.model_copy(update={"id": mid}), downsample(pts, c.voxel))
            mem.round_votes = _round_vote(phi.model.kind)
            if outcome == "replace":
                old = self.prims.pop(target.id)
                mem.points = downsample(mem.points, c.voxel, more=old.points)
                mem.primitive = refit(mem.primitive, mem.points.astype(np.float64), mid)
                mem.views = old.views + 1
                self._rename_edges(old.id, mid)
                for k, v in result.mapping.items():
                    if v == old.id:
                        result.mapping[k] = mid
                result.removed += 1
            self.prims[mid] = mem
            result.mapping[phi.id] = mid
            result.added += 1
            result.removed += self._join_pieces(mem, pieces, distance, result)
        if not whole:
            depth = ViewDepth(obs, c.through_cell)
            result.decayed = self._decay(visible, set(result.mapping.values()), depth)
            result.removed += result.decayed
            in_view = {m.id for m in visible} | set(result.mapping.values())
            self._look_below([self.prims[i] for i in in_view if i in self.prims], depth)
        self._combine_support(obs, result.mapping)
        result.removed += self._consolidate(set(result.mapping.values()), visible, result)
        self.n_views += 1
        self.version += 1
        self.last = result
        return result

    def _decay(
        self,
        visible: list[MemoryPrimitive],
        matched: set[int],
        depth: ViewDepth,
    ) -> int:
        """Negative evidence (``evidence.py``): the memory primitives in view that this view
        did not match and saw through count it; ``decay_views`` in a row (fewer for one
        seen in fewer views: as many as saw it) remove them (a moved or gone object, a veil
        of flying pixels). A match resets the count. And a
        primitive seen in one view only, whose surface ``unconfirmed_views`` later views
        saw where it lies (not hidden, not through) without any of their primitives
        matching it, was a segmentation of that view alone (noise, a sliver between two
        surfaces): it goes too. Returns how many went."""
        c = self.config
        if c.decay_views <= 0:
            return 0
        gone = 0
        for m in visible:
            if m.id not in self.prims:
                continue
            if m.id in matched:
                m.seen_through = 0
                continue
            through, evidence = depth.seen_through(m.points, c.through_margin)
            if evidence < c.through_points:
                continue
            if through > c.through_share * evidence:
                m.seen_through += 1
            elif m.views == 1 and c.unconfirmed_views > 0:
                m.unconfirmed += 1
            # as much evidence against as there was for: a primitive one view saw goes once
            # one view saw through it (the fetch-table arm's slivers), a table only after
            # ``decay_views`` in a row
            if m.seen_through >= min(c.decay_views, m.views) or (
                c.unconfirmed_views > 0 and m.unconfirmed >= c.unconfirmed_views
            ):
                self.prims.pop(m.id)
                gone += 1
        return gone

    def _same_round(self, a: MemoryPrimitive, b: MemoryPrimitive, share: float) -> bool:
        """Two memory cylinders or spheres of one round object overlapping by more than λ_p:
        views that each matched one of them, never the memory with itself (a mug held as
        three cylinders). Radii within ``radius``, each centre inside the other's body; not
        the axes: a cup's few cm of arc leave a cylinder's axis 20° off in one view."""
        pa, pb = a.primitive, b.primitive
        if {pa.model.kind, pb.model.kind} - ROUND:
            return False
        ra, rb = pa.model.radius, pb.model.radius
        if abs(ra - rb) > self.config.radius:
            return False
        apart = float(np.linalg.norm(np.asarray(pa.model.center) - pb.model.center))
        if apart > max(self.config.center, ra, rb):
            return False
        back = inlier(a.points, pb.obb, self.config.obb_margin, self._boxes)
        return max(share, back) > self.config.lambda_p

    def _vote_round(self, mem: MemoryPrimitive, phi: Primitive, votes: int | None = None) -> None:
        """A round object is the kind most of its views saw (``round_pair``): when a merge
        tips the vote, it is refitted as this view's kind on all its points. ``votes``: the
        merged one's own (a memory primitive joining), else this view's one."""
        kind = mem.primitive.model.kind
        if kind not in ROUND or phi.model.kind not in ROUND:
            return
        mem.round_votes += _round_vote(phi.model.kind) if votes is None else votes
        if phi.model.kind != kind and _round_vote(phi.model.kind) * mem.round_votes > 0:
            base = phi.model_copy(update={"id": mem.id})
            mem.primitive = refit(base, mem.points.astype(np.float64), mem.id)

    def _look_below(self, visible: list[MemoryPrimitive], depth: ViewDepth) -> None:
        """Count, for each memory primitive in view, whether this view saw through the space
        under its base (``Body.probes``; ``ViewDepth.seen_through`` on them, as negative
        evidence does): where a supporter would be, there is nothing."""
        c = self.config
        if c.below_views <= 0 or not visible:
            return
        bodies = self._stability_bodies()
        through, evidence = depth.seen_through_each(
            [bodies[m.id].probes for m in visible], c.through_margin
        )
        for m, t, e in zip(visible, through.tolist(), evidence.tolist(), strict=True):
            if e >= BELOW_EVIDENCE and t > c.through_share * e:
                m.below_free += 1

    def _join_pieces(
        self,
        target: MemoryPrimitive,
        pieces: list[MemoryPrimitive],
        distance: float,
        result: Update,
    ) -> int:
        """The other memory planes a new plane matched too (it bridged them: a table top seen
        first in two halves, then whole) join the one it merged into or replaced, where they
        agree with it (Algorithm 2 never compares the memory with itself, and keeps only the
        best match, so without this the halves stayed apart). Returns how many went."""
        c, gone = self.config, 0
        if target.primitive.model.kind != "plane":
            return 0
        for m in pieces:
            if m.id == target.id or m.id not in self.prims:
                continue
            if not compare_models(m.primitive, target.primitive, c, distance):
                continue
            self.prims.pop(m.id)
            self._merge_into(target, m.points.astype(np.float64))
            target.views += m.views - 1
            self._rename_edges(m.id, target.id)
            for k, v in result.mapping.items():
                if v == m.id:
                    result.mapping[k] = target.id
            gone += 1
        return gone

    def _not_annexed(
        self, solid: MemoryPrimitive, points: np.ndarray, visible: list[MemoryPrimitive]
    ) -> np.ndarray:
        """``points`` to merge into ``solid`` without those that lie outside it and inside
        another solid the memory holds: a box's side face seen as one plane with the side of
        the plank on it (generated scene 1012) would grow the box into the plank, and the
        support test would then rule out the plank's edge."""
        c = self.config
        outside = ~_inside(points, solid.primitive.obb, c.obb_margin)
        if not outside.any():
            return points
        theirs = np.zeros(len(points), bool)
        for m in visible:
            if (
                m.id != solid.id
                and m.id in self.prims
                and m.primitive.model.kind in SOLIDS
                and self._boxes.intersect(m.primitive.obb, solid.primitive.obb, c.plane_gap)
            ):
                theirs |= outside & _inside(points, m.primitive.obb, c.obb_margin)
        return points[~theirs] if theirs.any() else points

    def _spans_objects(
        self,
        p: Primitive,
        candidates: list[MemoryPrimitive],
        limit: int = 2,
        points: np.ndarray | None = None,
    ) -> bool:
        """Does ``p`` hold what the memory knows as separate things: ``limit`` or more
        solids, or planes off its surface (a box's own faces lie on it), or two primitives
        of which one supports the other? Inside: Inlier ≥ ``contained``. With ``p``'s
        ``points``, a solid holding more than λ_p of them is also one of its things for the
        support test: a segment across a contact (a box's top and the plank on it) covers
        neither whole, and would otherwise replace the one it covers most."""
        c = self.config
        inside, things = set(), 0
        for m in candidates:
            if m.id not in self.prims or not self._boxes.intersect(
                m.primitive.obb, p.obb, c.obb_margin
            ):
                continue
            kind = m.primitive.model.kind
            if inlier(m.points, p.obb, c.obb_margin, self._boxes) < c.contained:
                if (
                    points is not None
                    and kind in SOLIDS
                    and inlier(points, m.primitive.obb, c.obb_margin, self._boxes) > c.lambda_p
                ):
                    inside.add(m.id)
                continue
            inside.add(m.id)
            face = kind == "plane" and on_surface(p, m.points, c.face_distance)
            things += kind in SOLIDS or not face
        return things >= limit or any(a in inside and b in inside for a, b in self.occ)

    def _consolidate(
        self, touched: set[int], visible: list[MemoryPrimitive], result: Update
    ) -> int:
        """Pieces the memory holds of what a primitive of this view turned out to be: a face
        kept as a plane before its box was seen (Algorithm 2 compares the new view with the
        memory, never the memory with itself, so the order of the views decided). A plane
        whose points lie inside a solid touched by this view (> λ_o), or a solid inside
        another (φ ⊂ ψ), joins it. Returns how many primitives went."""
        c = self.config
        gone = 0
        for t in sorted(touched):
            if t not in self.prims or self.prims[t].primitive.model.kind not in SOLIDS:
                continue
            solid = self.prims[t]
            others = {m.id: m for m in visible} | {
                i: self.prims[i] for i in touched if i in self.prims
            }
            if self._spans_objects(solid.primitive, list(others.values()), limit=3):
                continue  # itself and two more: it spans objects the memory tells apart
            for m in others.values():
                if m.id == t or m.id not in self.prims or t not in self.prims:
                    continue
                if not self._boxes.intersect(solid.primitive.obb, m.primitive.obb, c.obb_margin):
                    continue
                share = inlier(m.points, solid.primitive.obb, c.obb_margin, self._boxes)
                kind = m.primitive.model.kind
                inside = (kind == "plane" and share > c.lambda_o) or (
                    kind in SOLIDS and share >= c.contained
                )
                if (
                    inside and on_surface(solid.primitive, m.points, c.surface_tolerance)
                ) or self._same_round(solid, m, share):
                    keep, drop = solid, m
                elif kind in SOLIDS and self._same_solid(solid, m, share):
                    # one thing held twice (Algorithm 2's "same", memory against memory):
                    # the one seen in more views takes the other's points
                    keep, drop = (solid, m) if solid.views >= m.views else (m, solid)
                else:
                    continue
                self.prims.pop(drop.id)
                views = max(keep.views, drop.views)
                self._merge_into(keep, drop.points.astype(np.float64))
                keep.views = views + 1
                if drop.primitive.model.kind in ROUND:
                    self._vote_round(keep, drop.primitive, drop.round_votes)
                self._rename_edges(drop.id, keep.id)
                for k, v in result.mapping.items():
                    if v == drop.id:
                        result.mapping[k] = keep.id
                gone += 1
                if drop is solid:
                    break
        return gone

    def _same_solid(self, a: MemoryPrimitive, b: MemoryPrimitive, share: float) -> bool:
        """Two solids of the memory that Algorithm 2 would call the same had one been the
        view's: each holds more than λ_o of the other's points (``share``: b's in a), and the
        points of one lie on the other's surface. A solid fused twice where a view's segment
        fell between the two (pose error of a centimetre or two, a face seen alone first)."""
        c = self.config
        if share <= c.lambda_o:
            return False
        if inlier(a.points, b.primitive.obb, c.obb_margin, self._boxes) <= c.lambda_o:
            return False
        tol = c.surface_tolerance
        return on_surface(a.primitive, b.points, tol) or on_surface(b.primitive, a.points, tol)

    def _floor_height(self, obs: SceneObservation) -> float | None:
        """Height of the lowest level plane known (memory or this view): the floor; None
        while none is near the world's ground (z = 0): a table top is no floor, and a tray
        on it is not a piece of one."""
        heights = [
            -p.model.d / p.model.normal[2]
            for p in [m.primitive for m in self.prims.values()] + list(obs.primitives)
            if p.model.kind == "plane" and abs(p.model.normal[2]) > np.cos(np.radians(10))
        ]
        lowest = min(heights, default=None)
        return lowest if lowest is not None and lowest < self.config.floor_max else None

    def _rename_edges(self, old: int, new: int) -> None:
        for (a, b), n in list(self.occ.items()):
            if old in (a, b):
                del self.occ[a, b]
                key = (new if a == old else a, new if b == old else b)
                if key[0] != key[1]:
                    self.occ[key] = max(self.occ.get(key, 0), n)

    def _combine_support(self, obs: SceneObservation, mapping: dict[int, int]) -> None:
        seen = set()
        for e in obs.support_edges:
            a, b = mapping.get(e.supporter), mapping.get(e.supported)
            if a is not None and b is not None and a != b:
                seen.add((a, b))
        if self.config.mode == "pc":
            self.occ = dict.fromkeys(seen, 1)
            return
        for key in seen:
            self.occ[key] = self.occ.get(key, 0) + 1
        for key in list(self.occ):
            if key[0] not in self.prims or key[1] not in self.prims:
                del self.occ[key]

    # -- the model as a message ---------------------------------------------------------------

    def support(self, shapes: _Shapes | None = None) -> dict[tuple[int, int], int]:
        """The support edges with occ(e) that the fused geometry allows. A ground surface (a
        level surface of ``ground_area``: a table top) and what lies under it within its
        footprint (its legs, its edge's faces, a shelf below) rest only on ground (the
        floor): legs holding a top up are parts of one piece of furniture, which the scene
        model cannot tell apart. And the supported one's bottom is not below the
        supporter's top (a box seen beside a shorter one, its lower part hidden by it,
        seemed to rest on it in that view): bottoms and tops of their points (``Body``: a
        box fitted to 2 m away Kinect points reaches centimetres past them). A primitive
        held by a and by m that a holds rests on m alone when its bottom is ``nearer_top``
        nearer m's top (support is direct: the thesis's graph has no edge that a chain of
        two gives). What does not rise ``level_with`` above a ground surface's top is a part
        of it (a piece of a table top fused in two, a face of its edge), not on it; what has its
        centre beside it is not on it either (``over_margin``). Structure
        (``_structure``: a wall, a cabinet's front) rests on nothing higher than the floor: a
        counter against a wall touches it, its top below the wall's visible foot, and seemed to
        hold it up."""
        c = self.config
        shapes = shapes or _Shapes()
        level, z_range = shapes.level_area, shapes.z_range
        grounds = [m.primitive for m in self.prims.values() if level(m.primitive) >= c.ground_area]
        bodies, out = self._stability_bodies(), {}

        def raised(p: Primitive) -> bool:  # above the floor, which ends where the walls stand
            return z_range(p.obb)[1] > c.floor_max

        for (a, b), n in self.occ.items():
            pa, pb = self.prims[a].primitive, self.prims[b].primitive
            on_ground = level(pa) >= c.ground_area
            if not on_ground and (
                level(pb) >= c.ground_area or _under(pb, grounds, c.rest_tolerance, z_range)
            ):
                continue
            if bodies[b].bottom < bodies[a].top - c.rest_tolerance:
                continue
            if on_ground and bodies[b].top <= bodies[a].top + c.level_with:
                continue  # a piece of the surface, a face of its edge
            if on_ground and raised(pa) and not _over(pb, pa, c.over_margin):
                continue  # beside a raised surface, its weight not on it: a side panel's top
            if z_range(pa.obb)[1] > c.floor_max and self._structure(pb, shapes):
                continue  # a wall stands on the floor, not on the counter against it
            out[a, b] = n
        return _direct(out, bodies, c.nearer_top)

    def unstable(
        self, support: dict[tuple[int, int], int] | None = None, shapes: _Shapes | None = None
    ) -> tuple[int | None, list[int]]:
        """ρ (the lowest primitive) and the primitives with no support chain to the ground
        that a view saw nothing under (``below_views``); those with none and nothing seen
        under them (their support hidden so far) go to ``self.unresolved``. ``support``:
        ``self.support()`` when already at hand."""
        if not self.prims:
            self.settled, self.unresolved = {}, []
            return None, []
        shapes = shapes or _Shapes()
        low = {
            i: m.primitive.obb.center[2]
            - np.abs(m.primitive.obb.rotation[2]) @ m.primitive.obb.extent / 2
            for i, m in self.prims.items()
        }
        root = min(low, key=low.get)
        ground = {root} | {
            i
            for i, m in self.prims.items()
            if shapes.level_area(m.primitive) >= self.config.ground_area
        }
        structure = {i for i, m in self.prims.items() if self._structure(m.primitive, shapes)}
        ground |= structure | self._attached(structure - ground)
        supports: dict[int, list[int]] = {}
        for a, b in support if support is not None else self.support(shapes):
            supports.setdefault(a, []).append(b)
        stable, settled = settle(
            self._stability_bodies(), ground, supports, self._stability, self._touches
        )
        self.settled = settled
        unsupported = set(self.prims) - stable
        views = self.config.below_views
        self.unresolved = sorted(
            i for i in unsupported if views > 0 and self.prims[i].below_free < views
        )
        return root, sorted(unsupported - set(self.unresolved))

    @property
    def _stability(self) -> StabilityConfig:
        c = self.config
        return StabilityConfig(
            rest_tolerance=c.rest_tolerance, margin=c.attached, floor_band=c.floor_band,
            floor_max=c.floor_max, ground_area=c.ground_area,
        )  # fmt: skip

    def _stability_bodies(self) -> dict[int, Body]:
        """Each memory primitive as ``stability`` sees it, kept while it is unchanged (its
        point sample's tree is built once)."""
        out = {}
        for i, m in self.prims.items():
            hit = self._bodies.get(i)
            if hit is None or hit.primitive is not m.primitive:
                hit = Body(m.primitive, m.points.astype(np.float64, copy=False))
            out[i] = hit
        self._bodies = out
        if len(self._touches) > 20 * len(out) + 1000:  # the pairs of primitives since gone
            self._touches = {k: v for k, v in self._touches.items() if v[0] is out.get(k[0])}
        return out

    def _structure(self, p: Primitive, shapes: _Shapes) -> bool:
        """An upright plane or box ``structure_height`` tall and ``structure_width`` wide."""
        c = self.config
        if p.model.kind not in ("plane", "box"):
            return False
        if p.model.kind == "plane" and abs(p.model.normal[2]) > np.sin(np.radians(15)):
            return False
        lo, hi = shapes.z_range(p.obb)
        R, e = p.obb.rotation, p.obb.extent
        width = float(np.max(np.linalg.norm(R[:2], axis=0) * e))  # widest level extent
        return hi - lo >= c.structure_height and width >= c.structure_width

    def _attached(self, structure: set[int]) -> set[int]:
        """The planes against a structure: ten of their points or more within ``attached`` of
        its box (a board's edge along the wall; not a solid beside it: an object stands on
        something). Each pair's answer is kept while both are unchanged."""
        c, out = self.config, set()
        walls = [(i, self.prims[i].primitive) for i in structure]
        if not walls:
            return out
        kept = self._against
        for i, m in self.prims.items():
            if i in structure or m.primitive.model.kind != "plane":
                continue
            for w, o in walls:
                hit = kept.get((i, w))
                if hit is None or hit[0] is not m.primitive or hit[1] is not o:
                    against = self._boxes.intersect(m.primitive.obb, o.obb, c.attached) and (
                        inlier(m.points, o.obb, c.attached, self._boxes) * len(m.points) >= 10
                    )
                    hit = kept[i, w] = (m.primitive, o, bool(against))
                if hit[2]:
                    out.add(i)
                    break
        if len(kept) > 20 * len(self.prims) + 1000:  # pairs of primitives since gone
            self._against = {k: v for k, v in kept.items() if k[0] in self.prims}
        return out

    _level_area = staticmethod(level_area)

    def spatial_edges(self) -> list[tuple[int, int]]:
        """Pairs of primitives whose OBBs, grown by ε, overlap (every pair in one kernel)."""
        ids = sorted(self.prims)
        if len(ids) < 2:
            return []
        obbs = [self.prims[i].primitive.obb for i in ids]
        hit = pairs_overlap(
            np.array([o.rotation for o in obbs]), np.array([o.center for o in obbs]),
            np.array([o.extent for o in obbs]), self.config.epsilon,
        )  # fmt: skip
        a, b = np.nonzero(np.triu(hit, 1))
        return [(ids[i], ids[j]) for i, j in zip(a.tolist(), b.tolist(), strict=True)]

    def _spatial_messages(self) -> list[SpatialEdge]:
        """``spatial_edges`` as messages, each pair's kept from the last model that had it
        (a kitchen model has ~2000, and building each anew cost more than finding them)."""
        last, edges = self._edge_messages, {}
        for pair in self.spatial_edges():
            e = last.get(pair)
            edges[pair] = e if e is not None else SpatialEdge.model_construct(a=pair[0], b=pair[1])
        self._edge_messages = edges
        return list(edges.values())

    def scene_model(
        self,
        seq: int = 0,
        stamp: float = 0.0,
        frame_seq: int | None = None,
        frame_stamp: float | None = None,
        fused_frames: list[int] | None = None,
    ) -> SceneModel:
        """The fused scene; ``frame_seq`` / ``frame_stamp``: the frame whose observation was
        fused last, ``fused_frames``: every frame whose observation this model is the first to
        hold (what a reader times the pipeline by)."""
        shapes = _Shapes()
        support = self.support(shapes)
        root, unstable = self.unstable(support, shapes)
        prims, messages = [], {}
        for i in sorted(self.prims):
            m = self.prims[i]
            cached = self._messages.get(i)
            if cached is not None and cached[0] is m.primitive and cached[1] is m.points:
                message = cached[2]  # unchanged since the last model (primitive and points)
            else:
                inliers = (
                    m.points
                    if len(m.points) <= 2000
                    else m.points[np.linspace(0, len(m.points) - 1, 2000).astype(int)]
                )
                message = m.primitive.model_copy(
                    update={"id": i, "inliers": inliers.astype(np.float32)}
                )
            messages[i] = (m.primitive, m.points, message)
            prims.append(message)
        self._messages = messages
        # (support edges: constructed, not validated one by one; the SceneModel checks that
        # every edge's ends exist)
        return SceneModel(
            seq=seq,
            stamp=stamp,
            model_version=self.version,
            n_views=self.n_views,
            fusion=self.config.mode,
            primitives=prims,
            spatial_edges=self._spatial_messages(),
            support_edges=[
                SupportEdge.model_construct(supporter=a, supported=b, occ=n)
                for (a, b), n in sorted(support.items())
            ],
            root_id=root,
            unstable_ids=unstable,
            unresolved_ids=self.unresolved,
            added=self.last.added,
            modified=self.last.modified,
            removed=self.last.removed,
            frame_seq=frame_seq,
            frame_stamp=frame_stamp,
            fused_frames=fused_frames or [],
        )


def warm_up() -> None:
    """Load (or compile) the fusion's kernels before the first observation: the boxes' tests
    and the points-in-box count, on arrays of the types the live path passes."""
    sat.warm_up()
    first_of_each(np.zeros(3, np.int64))
    _column_range(np.zeros((2, 3)))
    for a in (np.zeros((2, 3), np.float32), np.zeros((2, 3))):  # the types merges pass
        for b in (np.zeros((2, 3), np.float32), np.zeros((2, 3))):
            downsample(a, 0.01, more=b)
    box = Obb(center=np.zeros(3), rotation=np.eye(3), extent=np.ones(3))
    inlier(np.zeros((4, 3), np.float32), box, 0.01)
    inlier(np.zeros((4, 3)), box, 0.01)
    inlier(np.zeros((4, 3), np.float32), box, 0.01, _Boxes())
