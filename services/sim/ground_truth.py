"""Ground truth of a scene: its objects, and its support graph by the thesis's own definition.

A supports B iff removing A makes B lose its motionless state (3.2.2): remove A (disable its
collisions), simulate ``duration`` seconds, and B moved more than 1 cm or turned more than 2°.
Static parts cannot move in simulation, so static-on-static support (a table on the floor)
comes from contact geometry instead. The relation is transitive — remove the table and
everything on it falls — so two graphs are reported:

- ``support_closure``: every (A, B) with A supporting B, transitively closed;
- ``support_edges``: the direct ones, A and B in contact (what perception can see).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import mujoco
import numpy as np

from services.sim.scene import SceneInfo, body_id, owner_name
from services.sim.world import SLEEP, World

MOVE_TOLERANCE = 0.01  # m
TURN_TOLERANCE = math.radians(2.0)
REST_TOLERANCE = 0.005  # m: static B rests on static A when B's bottom is this close to A's top


@dataclass(frozen=True)
class GroundTruthObject:
    name: str
    kind: str
    pose: np.ndarray  # 4×4
    size: np.ndarray  # full extents in its own frame
    static: bool


def _owners(model: mujoco.MjModel) -> dict[str, list[int]]:
    owners: dict[str, list[int]] = {}
    for g in range(model.ngeom):
        owners.setdefault(owner_name(model, g), []).append(g)
    return owners


def geom_half_extents(model: mujoco.MjModel, g: int) -> np.ndarray:
    size, t = model.geom_size[g], model.geom_type[g]
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return size.copy()
    if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return np.array([size[0], size[0], size[1]])
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return np.full(3, size[0])
    if t == mujoco.mjtGeom.mjGEOM_PLANE:
        return np.array([size[0] or 1e3, size[1] or 1e3, 0.0])
    return model.geom_rbound[g] * np.ones(3)


def _world_aabb(
    model: mujoco.MjModel, data: mujoco.MjData, geoms: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for g in geoms:
        R = data.geom_xmat[g].reshape(3, 3)
        half = np.abs(R) @ geom_half_extents(model, g)
        c = data.geom_xpos[g]
        lo, hi = np.minimum(lo, c - half), np.maximum(hi, c + half)
    return lo, hi


def _pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, p
    return T


def objects(world: World) -> list[GroundTruthObject]:
    """Every vertex of the support graph: kind (geom type, ``compound`` for several geoms), pose
    and full extents (of its one geom, or of its bounding box in its body frame)."""
    m, d = world.model, world.data
    owners = _owners(m)
    out = []
    for name in world.info.vertices:
        geoms = owners.get(name, [])
        static = name in world.info.statics
        if len(geoms) == 1:
            g = geoms[0]
            kind = mujoco.mjtGeom(m.geom_type[g]).name.removeprefix("mjGEOM_").lower()
            pose = _pose(d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g])
            size = 2 * geom_half_extents(m, g)
        else:
            b = body_id(m, name)
            R, p = d.xmat[b].reshape(3, 3), d.xpos[b]
            lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            for g in geoms:
                Rg = R.T @ d.geom_xmat[g].reshape(3, 3)
                cg = R.T @ (d.geom_xpos[g] - p)
                half = np.abs(Rg) @ geom_half_extents(m, g)
                lo, hi = np.minimum(lo, cg - half), np.maximum(hi, cg + half)
            kind = "compound"
            pose = _pose(R, p + R @ ((lo + hi) / 2))
            size = hi - lo
        out.append(GroundTruthObject(name, kind, pose, size, static))
    return out


def _turned(q0: np.ndarray, q1: np.ndarray) -> float:
    return 2 * math.acos(min(1.0, abs(float(np.dot(q0, q1)))))


def _static_support(
    model: mujoco.MjModel, data: mujoco.MjData, info: SceneInfo, owners: dict[str, list[int]]
) -> set[tuple[str, str]]:
    """Static B rests on static A: B's bottom meets A's top and their footprints overlap."""
    boxes = {n: _world_aabb(model, data, owners[n]) for n in info.statics if n in owners}
    edges = set()
    for b, (b_lo, b_hi) in boxes.items():
        for a, (a_lo, a_hi) in boxes.items():
            if a == b or abs(b_lo[2] - a_hi[2]) > REST_TOLERANCE:
                continue
            if np.all(b_lo[:2] < a_hi[:2]) and np.all(a_lo[:2] < b_hi[:2]):
                edges.add((a, b))
    return edges


def _contacts(model: mujoco.MjModel, data: mujoco.MjData) -> set[frozenset[str]]:
    pairs = set()
    for c in data.contact[: data.ncon]:
        a, b = (owner_name(model, int(g)) for g in c.geom)
        if a and b and a != b and "robot" not in (a, b):
            pairs.add(frozenset((a, b)))
    return pairs


def _closure(edges: set[tuple[str, str]]) -> set[tuple[str, str]]:
    closed = set(edges)
    while True:
        extra = {(a, d) for a, b in closed for c, d in closed if b == c and a != d} - closed
        if not extra:
            return closed
        closed |= extra


def _awake(data: mujoco.MjData) -> mujoco.MjData:
    """A copy of ``data`` with every tree awake (``tree_asleep`` < 0)."""
    d = copy.copy(data)
    d.tree_asleep[:] = -1
    return d


def support_graph(
    model: mujoco.MjModel, data: mujoco.MjData, info: SceneInfo, duration: float = 0.5
) -> tuple[list[tuple[str, str]], list[tuple[str, str]]]:
    """(support_edges, support_closure) of the state ``data``, each sorted. Works on copies:
    the caller's model and data are left as they are. Sleep is off in the copies (every tree
    awake): a sleeping object neither falls when its support goes nor has contacts."""
    m = copy.copy(model)
    m.opt.enableflags &= ~SLEEP
    owners = _owners(m)
    bodies = {n: m.body(n).id for n in info.objects}
    static = _static_support(m, data, info, owners)
    relation = set(static)
    steps = round(duration / m.opt.timestep)
    for removed in info.vertices:
        geoms = owners.get(removed, [])
        saved = (m.geom_contype[geoms].copy(), m.geom_conaffinity[geoms].copy())
        m.geom_contype[geoms] = 0
        m.geom_conaffinity[geoms] = 0
        d = _awake(data)
        start = {n: (d.xpos[b].copy(), d.xquat[b].copy()) for n, b in bodies.items()}
        for _ in range(steps):
            mujoco.mj_step(m, d)
        for n, b in bodies.items():
            p0, q0 = start[n]
            if n != removed and (
                np.linalg.norm(d.xpos[b] - p0) > MOVE_TOLERANCE
                or _turned(q0, d.xquat[b]) > TURN_TOLERANCE
            ):
                relation.add((removed, n))
        m.geom_contype[geoms], m.geom_conaffinity[geoms] = saved
    awake = _awake(data)
    mujoco.mj_forward(m, awake)
    in_contact = _contacts(m, awake)
    direct = {(a, b) for a, b in relation if frozenset((a, b)) in in_contact or (a, b) in static}
    return sorted(direct), sorted(_closure(relation))


def segmentation_labels(world: World) -> tuple[list[str], np.ndarray]:
    """Labels (the graph's vertices, then 'robot') and a lookup geom id → label index (-1)."""
    labels = [*world.info.vertices, "robot"]
    index = {n: i for i, n in enumerate(labels)}
    lookup = np.array(
        [index.get(owner_name(world.model, g), -1) for g in range(world.model.ngeom)],
        dtype=np.int32,
    )
    return labels, lookup
