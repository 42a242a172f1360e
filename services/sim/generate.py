"""Random table-top scenes: a table, 3–8 household objects in arrangements (single, stack,
bridge, hidden behind an occluder, touching side by side) and a robot start pose around it.

Pure (numpy and MuJoCo, no transport) and deterministic for a seed: every draw comes from one
``numpy.random.default_rng(seed)``. The objects are settled by physics before the text is
written; a layout that does not settle as planned (an object fell off, toppled, sank or slid)
is redrawn from the same generator.
"""

from __future__ import annotations

import colorsys
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace

import mujoco
import numpy as np

from services.sim.world import wrap

EDGE_MARGIN = 0.03  # m: objects keep this far inside the table top's edges
GROUP_GAP = 0.03  # m: between two arrangements
DROP = 0.0015  # m: an object's bottom starts this far above what it stands on
ROBOT_DISTANCE = (0.5, 2.5)  # m: robot_start to the table top's footprint (0.45 m radius + 5 cm)
FACING_AWAY = 0.25  # share of robot starts that face away from the table
AWAY_ANGLE = math.radians(110)  # facing away: at least this far off the table's direction
TOWARD_ANGLE = math.radians(40)  # facing it: at most this far off
SETTLE_S = 2.0  # s of physics at most to settle a layout
REST_SPEED = 1e-3  # m/s: an object rests below this speed
REST_SPIN = 0.01  # rad/s ... and this angular speed
MAX_TILT = math.radians(5)  # settling may not topple an object more than this
MAX_SINK = 0.02  # m ... lower it more than this
MAX_SLIDE = 0.02  # m ... or shift it sideways more than this
STILL_S = 1.0  # s: the written scene is simulated this long and must not move
STILL_MOVE = 1e-3  # m ... more than this
OVERLAP = 1e-3  # m: deepest interpenetration allowed at start (the sim's limit)
MAX_ATTEMPTS = 50
ROI_MARGIN, ROI_BELOW, ROI_ABOVE = 0.05, 0.03, 0.10  # m
FLOOR_RGB = (0.75, 0.75, 0.72)
FURNITURE_RGB = (  # oak, walnut, cherry, white laminate, grey, black, beech
    (0.70, 0.55, 0.35),
    (0.45, 0.30, 0.18),
    (0.55, 0.28, 0.18),
    (0.88, 0.87, 0.84),
    (0.50, 0.50, 0.50),
    (0.20, 0.20, 0.20),
    (0.80, 0.65, 0.45),
)
MIN_COLOUR_DISTANCE = 0.35  # RGB distance between any two objects (and the table, the floor)
TEXTURED = 0.25  # share of objects with a checker texture


class GenerationError(RuntimeError):
    """No layout of a seed settled as planned."""


@dataclass(frozen=True)
class Table:
    """The table: its top's centre (x, y) and yaw, half extents, thickness and the height of
    its top surface (m, rad)."""

    x: float
    y: float
    yaw: float
    half_length: float
    half_depth: float
    thickness: float
    height: float
    rgb: tuple[float, float, float]
    #: a shelf: the lower board's top height (m); the top is then the upper board, between two
    #: side panels, no back; None: a table on four legs
    lower: float | None = None

    @property
    def kind(self) -> str:
        return "table" if self.lower is None else "shelf"

    @property
    def half(self) -> np.ndarray:
        return np.array([self.half_length, self.half_depth])

    def _rotation(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s], [s, c]])

    def to_world(self, uv: np.ndarray) -> np.ndarray:
        """A point in the table frame (x along its length) to world x, y."""
        return np.array([self.x, self.y]) + self._rotation() @ np.asarray(uv)

    def to_table(self, xy: np.ndarray) -> np.ndarray:
        return self._rotation().T @ (np.asarray(xy) - np.array([self.x, self.y]))

    def distance(self, xy: np.ndarray) -> float:
        """Distance from a floor point to the table top's footprint (0 inside)."""
        outside = np.maximum(np.abs(self.to_table(xy)) - self.half, 0.0)
        return float(np.linalg.norm(outside))

    def aabb(self) -> tuple[np.ndarray, np.ndarray]:
        """The top's axis-aligned bounding box in world x, y."""
        reach = np.abs(self._rotation()) @ self.half
        centre = np.array([self.x, self.y])
        return centre - reach, centre + reach


@dataclass(frozen=True)
class Arrangement:
    """Objects placed together. ``objects`` in role order: single (x,), stack (bottom, top),
    bridge (support, support, plank), hidden (occluder, hidden), touching (a, b)."""

    kind: str
    objects: tuple[str, ...]

    def __str__(self) -> str:
        o = self.objects
        match self.kind:
            case "stack":
                return f"stack: {o[1]} on {o[0]}"
            case "bridge":
                return f"bridge: {o[2]} on {o[0]}, {o[1]}"
            case "hidden":
                return f"hidden: {o[1]} behind {o[0]}"
            case _:
                return f"{self.kind}: {', '.join(o)}"

    @property
    def on_table(self) -> tuple[str, ...]:
        """The objects standing on the table top."""
        if self.kind == "stack":
            return self.objects[:1]
        return self.objects[:2] if self.kind == "bridge" else self.objects

    @property
    def supports(self) -> list[tuple[str, str]]:
        """(supporter, supported) within the arrangement."""
        o = self.objects
        if self.kind == "stack":
            return [(o[0], o[1])]
        return [(o[0], o[2]), (o[1], o[2])] if self.kind == "bridge" else []


@dataclass(frozen=True)
class GeneratedScene:
    """A generated scene: its MJCF text and what was planned."""

    seed: int
    text: str
    table: Table
    robot_start: tuple[float, float, float]  # x, y, yaw
    arrangements: tuple[Arrangement, ...]
    rejected: tuple[str, ...]  # why each layout drawn before this one was redrawn

    @property
    def objects(self) -> list[str]:
        return [name for a in self.arrangements for name in a.objects]

    @property
    def support_edges(self) -> set[tuple[str, str]]:
        """The direct support edges as planned (floor → table → objects → objects)."""
        edges = {("floor", "table")}
        for a in self.arrangements:
            edges |= {("table", name) for name in a.on_table} | set(a.supports)
        return edges


@dataclass(frozen=True)
class _Part:
    """An object of an arrangement, in the arrangement's frame: centre (u, v) and the height of
    its bottom above the table top."""

    label: str  # name prefix: box, cylinder, sphere, plank
    kind: str  # geom type
    size: tuple[float, ...]  # MJCF size
    u: float = 0.0
    v: float = 0.0
    bottom: float = DROP

    @property
    def half(self) -> np.ndarray:
        """Half extents (x, y, z)."""
        s = self.size
        if self.kind == "box":
            return np.array(s)
        return np.array((s[0], s[0], s[1]) if self.kind == "cylinder" else (s[0],) * 3)

    @property
    def top(self) -> float:
        return self.bottom + 2 * float(self.half[2])


@dataclass(frozen=True)
class _Object:
    """A placed object: world pose, colour and (if textured) the checker's second colour."""

    name: str
    kind: str
    size: tuple[float, ...]
    pos: np.ndarray
    quat: np.ndarray  # w, x, y, z
    rgb: tuple[float, float, float]
    rgb2: tuple[float, float, float] | None


# -- drawing the table and the robot -----------------------------------------------------------


def draw_table(rng: np.random.Generator) -> Table:
    """A table 0.6–1.6 × 0.5–1.0 m, top 0.6–0.9 m high, 1–2 m from the origin, any yaw."""
    return _furniture(rng, (1.0, 2.0), (0.3, 0.8), (0.25, 0.5), (0.03, 0.05), (0.6, 0.9))


def draw_shelf(rng: np.random.Generator) -> Table:
    """An open shelf (issue 43): two boards 0.7-1.0 × 0.3-0.44 m between two side panels, the
    upper one's top 0.85-1.05 m high (below the head camera, so its top is seen from a step
    back), the lower one's 0.35-0.5 m; 1.2-2 m from the origin, any yaw."""
    table = _furniture(rng, (1.2, 2.0), (0.35, 0.5), (0.15, 0.22), (0.02, 0.03), (0.85, 1.05))
    return replace(table, lower=_mm(rng, 0.35, 0.5))


def _furniture(
    rng: np.random.Generator,
    distance: tuple[float, float],
    half_length: tuple[float, float],
    half_depth: tuple[float, float],
    thickness: tuple[float, float],
    height: tuple[float, float],
) -> Table:
    """A table's top drawn from these ranges (m), at a distance from the origin in any
    direction, any yaw, a furniture colour (the draws' order is the generator's contract: a
    seed's scene stays the same)."""
    d, bearing = rng.uniform(*distance), rng.uniform(-math.pi, math.pi)
    rgb = np.clip(
        FURNITURE_RGB[rng.integers(len(FURNITURE_RGB))] + rng.uniform(-0.04, 0.04, 3), 0, 1
    )
    return Table(
        x=float(d * math.cos(bearing)),
        y=float(d * math.sin(bearing)),
        yaw=float(rng.uniform(-math.pi, math.pi)),
        half_length=_mm(rng, *half_length),
        half_depth=_mm(rng, *half_depth),
        thickness=_mm(rng, *thickness),
        height=_mm(rng, *height),
        rgb=tuple(round(float(c), 3) for c in rgb),
    )


def draw_robot_start(rng: np.random.Generator, table: Table) -> tuple[float, float, float]:
    """(x, y, yaw) on the floor 0.5–2.5 m from the table's footprint; facing the table (within
    40°) or, one time in four, away from it (more than 110° off)."""
    reach = table.half + ROBOT_DISTANCE[1]
    while True:
        xy = table.to_world(rng.uniform(-reach, reach))
        if ROBOT_DISTANCE[0] <= table.distance(xy) <= ROBOT_DISTANCE[1]:
            break
    toward = math.atan2(table.y - xy[1], table.x - xy[0])
    if rng.random() < FACING_AWAY:
        offset = rng.uniform(AWAY_ANGLE, math.pi) * rng.choice([-1.0, 1.0])
    else:
        offset = rng.uniform(-TOWARD_ANGLE, TOWARD_ANGLE)
    return float(xy[0]), float(xy[1]), wrap(toward + offset)


def heading_offset(robot_start: tuple[float, float, float], table: Table) -> float:
    """How far (rad, 0–π) the robot's heading is off the direction to the table's centre."""
    x, y, yaw = robot_start
    return abs(wrap(yaw - math.atan2(table.y - y, table.x - x)))


# -- drawing the arrangements -------------------------------------------------------------------


def _mm(rng: np.random.Generator, lo: float, hi: float) -> float:
    """A length drawn uniformly from [lo, hi], to the millimetre."""
    return round(float(rng.uniform(lo, max(lo, hi))), 3)


def _box(rng: np.random.Generator, lo: float, hi: float, z: tuple[float, float]) -> _Part:
    """A box; its height at most 2.5 times its narrower width."""
    hx, hy = _mm(rng, lo, hi), _mm(rng, lo, hi)
    return _Part("box", "box", (hx, hy, _mm(rng, z[0], min(z[1], 2.5 * min(hx, hy)))))


def _cylinder(rng: np.random.Generator, r: tuple[float, float], hh: tuple[float, float]) -> _Part:
    """An upright cylinder; its height at most 3 times its diameter."""
    radius = _mm(rng, *r)
    return _Part("cylinder", "cylinder", (radius, _mm(rng, hh[0], min(hh[1], 3 * radius))))


def _sphere(rng: np.random.Generator, r: tuple[float, float]) -> _Part:
    return _Part("sphere", "sphere", (_mm(rng, *r),))


def _any_shape(rng: np.random.Generator, small: bool = False) -> _Part:
    """A household box, cylinder or sphere (half extents 2.5–12 cm; small: 2.5–6 cm)."""
    kind = rng.choice(["box", "cylinder", "sphere"], p=[0.45, 0.35, 0.2])
    if kind == "box":
        return _box(rng, 0.025, 0.05 if small else 0.1, (0.025, 0.05 if small else 0.12))
    if kind == "cylinder":
        return _cylinder(rng, (0.025, 0.045 if small else 0.07), (0.03, 0.06 if small else 0.12))
    return _sphere(rng, (0.03, 0.05 if small else 0.08))


def _single(rng: np.random.Generator) -> list[_Part]:
    return [_any_shape(rng)]


def _stack(rng: np.random.Generator) -> list[_Part]:
    """A box or cylinder standing on a box with an equal or larger footprint."""
    bottom = _box(rng, 0.05, 0.12, (0.025, 0.07))
    bx, by, _ = bottom.size
    if rng.random() < 0.5:
        top = _box(rng, 0.025, min(bx, by), (0.025, 0.1))
    else:
        top = _cylinder(rng, (0.025, min(bx, by, 0.07)), (0.03, 0.1))
    slack = (bottom.half[:2] - top.half[:2]) / 2
    u, v = rng.uniform(-slack, slack)
    return [bottom, replace(top, u=float(u), v=float(v), bottom=bottom.top + DROP)]


def _bridge(rng: np.random.Generator) -> list[_Part]:
    """A plank lying across two boxes of equal height, each end over a box's outer half."""
    half_length = _mm(rng, 0.1, 0.15)
    sx = _mm(rng, 0.03, min(0.05, (half_length - 0.03) / 2))
    s = half_length - sx + float(rng.uniform(0.0, sx / 2))
    sz = _mm(rng, 0.03, 0.08)
    supports = [_Part("box", "box", (sx, _mm(rng, 0.03, 0.06), sz), u=u) for u in (-s, s)]
    plank = _Part(
        "plank", "box", (half_length, _mm(rng, 0.03, 0.07), 0.02), bottom=supports[0].top + DROP
    )
    return [*supports, plank]


def _hidden(rng: np.random.Generator) -> list[_Part]:
    """A small object right behind a taller, wider box (the arrangement's +u points away from
    the robot)."""
    hidden = _any_shape(rng, small=True)
    hx, hy, hz = hidden.half
    oy = min(0.15, round(hy + _mm(rng, 0.03, 0.07), 3))
    oz = min(0.15, round(hz + _mm(rng, 0.04, 0.08), 3))
    occluder = _Part("box", "box", (_mm(rng, 0.03, 0.05), oy, oz))
    u = occluder.size[0] + float(rng.uniform(0.01, 0.03)) + hx
    v = float(rng.uniform(-1, 1)) * (oy - hy) / 2
    return [occluder, replace(hidden, u=float(u), v=v)]


def _touching(rng: np.random.Generator) -> list[_Part]:
    """Two boxes face to face, 1–2 mm apart."""
    a = _box(rng, 0.03, 0.08, (0.03, 0.1))
    b = _box(rng, 0.03, 0.08, (0.03, 0.1))
    gap = float(rng.uniform(0.001, 0.002))
    v = float(rng.uniform(-1, 1)) * min(a.size[1], b.size[1]) / 2
    return [replace(a, u=-a.size[0] - gap / 2), replace(b, u=b.size[0] + gap / 2, v=v)]


#: kind → (number of objects, builder, weight)
ARRANGEMENTS: dict[str, tuple[int, Callable[[np.random.Generator], list[_Part]], float]] = {
    "single": (1, _single, 1.0),
    "stack": (2, _stack, 1.5),
    "bridge": (3, _bridge, 1.0),
    "hidden": (2, _hidden, 1.0),
    "touching": (2, _touching, 1.0),
}


def _footprint(parts: list[_Part], origin: np.ndarray, phi: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned bounding box (table frame) of the parts turned by phi about origin."""
    c, s = math.cos(phi), math.sin(phi)
    R = np.array([[c, -s], [s, c]])
    centres = np.array([[p.u, p.v] for p in parts]) @ R.T + origin
    reach = np.array([np.abs(R) @ p.half[:2] for p in parts])
    return (centres - reach).min(axis=0), (centres + reach).max(axis=0)


def _apart(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    return bool(np.any(a[0] >= b[1] + GROUP_GAP) or np.any(b[0] >= a[1] + GROUP_GAP))


def _place(
    rng: np.random.Generator,
    table: Table,
    parts: list[_Part],
    taken: list[tuple[np.ndarray, np.ndarray]],
    facing_from: np.ndarray | None,
    tries: int = 100,
) -> tuple[np.ndarray, float] | None:
    """(origin, yaw) in the table frame where the parts fit on the top, clear of the other
    arrangements; yaw points away from ``facing_from`` if given, else random."""
    limit = table.half - EDGE_MARGIN
    for _ in range(tries):
        origin = rng.uniform(-limit, limit)
        if facing_from is None:
            phi = rng.uniform(-math.pi, math.pi)
        else:
            phi = math.atan2(*(origin - facing_from)[::-1])
        box = _footprint(parts, origin, phi)
        if (
            np.all(box[0] >= -limit)
            and np.all(box[1] <= limit)
            and all(_apart(box, t) for t in taken)
        ):
            taken.append(box)
            return origin, phi
    return None


def _colours(rng: np.random.Generator, n: int, avoid: list[tuple[float, ...]]) -> list[np.ndarray]:
    """n saturated colours, every two (and each and ``avoid``) clearly apart."""
    out: list[np.ndarray] = []
    for _ in range(100_000):
        if len(out) == n:
            return out
        rgb = np.array(
            colorsys.hsv_to_rgb(rng.random(), rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.95))
        )
        if all(np.linalg.norm(rgb - np.asarray(o)) >= MIN_COLOUR_DISTANCE for o in [*avoid, *out]):
            out.append(rgb)
    raise GenerationError(f"no {n} distinct colours found")


def _yaw_quat(yaw: float) -> np.ndarray:
    return np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])


def _draw_layout(
    rng: np.random.Generator, table: Table, robot_start: tuple[float, float, float]
) -> tuple[list[_Object], list[Arrangement]]:
    """3–8 objects in arrangements on the table top (fewer when the table is full); on a
    shelf's upper board a stack and 0-2 single objects."""
    shelf = table.lower is not None
    target = int(rng.integers(2, 5)) if shelf else int(rng.integers(3, 9))
    robot_uv = table.to_table(robot_start[:2])
    taken: list[tuple[np.ndarray, np.ndarray]] = []
    groups: list[tuple[str, list[_Part], np.ndarray, float]] = []
    count, failures = 0, 0
    while count < target and failures < 10:
        kinds = [k for k, (n, _, _) in ARRANGEMENTS.items() if n <= target - count]
        if shelf:
            kinds = ["single"] if groups else ["stack"]
        if not kinds:
            break
        weights = np.array([ARRANGEMENTS[k][2] for k in kinds])
        kind = str(rng.choice(kinds, p=weights / weights.sum()))
        parts = ARRANGEMENTS[kind][1](rng)
        placed = _place(rng, table, parts, taken, robot_uv if kind == "hidden" else None)
        if placed is None:
            failures += 1
            continue
        groups.append((kind, parts, *placed))
        count += len(parts)
    colours = _colours(rng, count, [table.rgb, FLOOR_RGB])
    objects, arrangements = [], []
    for kind, parts, origin, phi in groups:
        names = []
        c, s = math.cos(phi), math.sin(phi)
        for part in parts:
            i = len(objects)
            name = f"{part.label}_{i}"
            uv = origin + np.array([c * part.u - s * part.v, s * part.u + c * part.v])
            z = table.height + part.bottom + part.half[2]
            rgb = np.round(colours[i], 3)
            rgb2 = (
                tuple(float(x) for x in np.round(0.35 * rgb, 3))
                if rng.random() < TEXTURED
                else None
            )
            objects.append(
                _Object(
                    name=name,
                    kind=part.kind,
                    size=part.size,
                    pos=np.array([*table.to_world(uv), z]),
                    quat=_yaw_quat(table.yaw + phi),
                    rgb=tuple(float(x) for x in rgb),
                    rgb2=rgb2,
                )
            )
            names.append(name)
        arrangements.append(Arrangement(kind, tuple(names)))
    return objects, arrangements


# -- MJCF text ----------------------------------------------------------------------------------


def _num(value: float) -> str:
    text = f"{value:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("", "-0") else text


def _vec(values: Iterable[float]) -> str:
    return " ".join(_num(float(v)) for v in values)


def _roi(table: Table, objects: list[_Object]) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half extents): the table top's AABB plus a margin, from just below the top
    surface to 10 cm above the highest object."""
    lo, hi = table.aabb()
    top = max(_object_top(o) for o in objects)
    lo = np.array([*(lo - ROI_MARGIN), table.height - ROI_BELOW])
    hi = np.array([*(hi + ROI_MARGIN), top + ROI_ABOVE])
    return (lo + hi) / 2, (hi - lo) / 2


def _object_top(o: _Object) -> float:
    R = np.empty(9)
    mujoco.mju_quat2Mat(R, o.quat)
    half = _Part("", o.kind, o.size).half
    return float(o.pos[2] + np.abs(R.reshape(3, 3)[2]) @ half)


def _header(
    seed: int,
    table: Table,
    robot_start: tuple[float, float, float],
    arrangements: list[Arrangement],
) -> list[str]:
    n = sum(len(a.objects) for a in arrangements)
    away = heading_offset(robot_start, table) > math.radians(100)
    size = f"{2 * table.half_length:.2f} × {2 * table.half_depth:.2f} m"
    distance = table.distance(np.array(robot_start[:2]))
    return [
        "<!--",
        f"  Generated by services/sim/generate.py (avs scene generate), seed {seed}: a {size}",
        f"  {table.kind}, top {table.height:.3f} m high, {n} objects settled by physics;",
        f"  robot_start {distance:.2f} m from it, facing {'away from' if away else 'towards'} it.",
        "  Arrangements:",
        *(f"    {a}" for a in arrangements),
        "-->",
    ]


def _assets(objects: list[_Object]) -> list[str]:
    lines = []
    for o in objects:
        if o.rgb2 is None:
            continue
        lines += [
            f'    <texture name="tex_{o.name}" type="2d" builtin="checker" rgb1="{_vec(o.rgb)}"'
            f' rgb2="{_vec(o.rgb2)}" width="256" height="256"/>',
            f'    <material name="mat_{o.name}" texture="tex_{o.name}" texrepeat="20 20"'
            ' texuniform="true"/>',
        ]
    return ["  <asset>", *lines, "  </asset>"] if lines else []


def _shelf_body(table: Table) -> list[str]:
    """Two boards between two side panels (1.5 cm) that rise 5 cm above the upper board."""
    panel = 0.015
    top_z = table.height + 0.05
    board = (table.half_length, table.half_depth, table.thickness / 2)
    boards = [
        f'      <geom name="{name}" type="box" size="{_vec(board)}"'
        f' pos="0 0 {_num(z - table.thickness / 2)}"/>'
        for name, z in (("board_low", table.lower), ("table_top", table.height))
    ]
    panels = [
        f'      <geom type="box" size="{_vec((panel, table.half_depth, top_z / 2))}"'
        f' pos="{_vec((sx * (table.half_length + panel), 0, top_z / 2))}"/>'
        for sx in (1, -1)
    ]
    return [
        f'    <body name="table" pos="{_vec((table.x, table.y, 0))}" euler="0 0 {_num(table.yaw)}"'
        ' childclass="furniture">',
        *boards,
        *panels,
        "    </body>",
    ]


def _table_body(table: Table) -> list[str]:
    if table.lower is not None:
        return _shelf_body(table)
    leg = 0.025
    leg_z = (table.height - table.thickness) / 2
    corners = table.half - leg - 0.03
    legs = [
        f'      <geom type="box" size="{_vec((leg, leg, leg_z))}"'
        f' pos="{_vec((sx * corners[0], sy * corners[1], leg_z))}"/>'
        for sx in (1, -1)
        for sy in (1, -1)
    ]
    top = (table.half_length, table.half_depth, table.thickness / 2)
    return [
        f'    <body name="table" pos="{_vec((table.x, table.y, 0))}" euler="0 0 {_num(table.yaw)}"'
        ' childclass="furniture">',
        f'      <geom name="table_top" type="box" size="{_vec(top)}"'
        f' pos="0 0 {_num(table.height - table.thickness / 2)}"/>',
        *legs,
        "    </body>",
    ]


def _object_body(o: _Object) -> list[str]:
    look = f'material="mat_{o.name}"' if o.rgb2 is not None else f'rgba="{_vec((*o.rgb, 1))}"'
    return [
        f'    <body name="{o.name}" pos="{_vec(o.pos)}" quat="{_vec(o.quat)}" childclass="object">',
        "      <freejoint/>",
        f'      <geom type="{o.kind}" size="{_vec(o.size)}" {look}/>',
        "    </body>",
    ]


def _mjcf(
    seed: int,
    table: Table,
    robot_start: tuple[float, float, float],
    objects: list[_Object],
    arrangements: list[Arrangement],
) -> str:
    roi_centre, roi_half = _roi(table, objects)
    x, y, yaw = robot_start
    lines = [
        *_header(seed, table, robot_start, arrangements),
        f'<mujoco model="generated_{seed}">',
        '  <compiler angle="radian"/>',
        '  <option timestep="0.001" integrator="implicitfast"/>',
        "  <visual>",
        '    <headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/>',
        '    <map znear="0.01" zfar="30"/>',
        "  </visual>",
        *_assets(objects),
        "  <default>",
        '    <default class="furniture">',
        f'      <geom rgba="{_vec((*table.rgb, 1))}"/>',
        "    </default>",
        '    <default class="object">',
        '      <geom density="500" friction="0.9 0.01 0.001"/>',
        "    </default>",
        "  </default>",
        "",
        "  <worldbody>",
        f'    <light name="sun" pos="{_vec((table.x, table.y, 4))}" dir="0 0 -1"'
        ' diffuse="0.5 0.5 0.5"/>',
        f'    <geom name="floor" type="plane" size="8 8 0.1" rgba="{_vec((*FLOOR_RGB, 1))}"/>',
        "",
        *_table_body(table),
        "",
        *(line for o in objects for line in _object_body(o)),
        "",
        f'    <site name="robot_start" pos="{_vec((x, y, 0))}" euler="0 0 {_num(yaw)}"/>',
        f'    <site name="roi" type="box" pos="{_vec(roi_centre)}" size="{_vec(roi_half)}"/>',
        "  </worldbody>",
        "</mujoco>",
        "",
    ]
    return "\n".join(lines)


# -- settling -----------------------------------------------------------------------------------


def _free_dofs(model: mujoco.MjModel, objects: list[_Object]) -> list[tuple[int, int]]:
    """(body id, first dof) of each object."""
    out = []
    for o in objects:
        b = model.body(o.name).id
        out.append((b, int(model.jnt_dofadr[model.body_jntadr[b]])))
    return out


def _at_rest(data: mujoco.MjData, dofs: list[tuple[int, int]]) -> bool:
    return all(
        np.linalg.norm(data.qvel[d : d + 3]) < REST_SPEED
        and np.linalg.norm(data.qvel[d + 3 : d + 6]) < REST_SPIN
        for _, d in dofs
    )


def _tilt(q0: np.ndarray, q1: np.ndarray) -> float:
    """Angle between the z axes of two orientations."""
    z = []
    for q in (q0, q1):
        R = np.empty(9)
        mujoco.mju_quat2Mat(R, q)
        z.append(R.reshape(3, 3)[:, 2])
    return math.acos(min(1.0, float(np.dot(*z))))


def _went_wrong(planned: _Object, settled: _Object, table: Table) -> str | None:
    """Why a settled object is not where it was planned, or None."""
    name = planned.name
    uv = np.abs(table.to_table(settled.pos[:2]))
    if settled.pos[2] < table.height or np.any(uv > table.half):
        return f"{name} fell off the table"
    if planned.pos[2] - settled.pos[2] > MAX_SINK:
        return f"{name} sank {100 * (planned.pos[2] - settled.pos[2]):.1f} cm"
    if planned.kind != "sphere" and _tilt(planned.quat, settled.quat) > MAX_TILT:
        return f"{name} toppled ({math.degrees(_tilt(planned.quat, settled.quat)):.0f}°)"
    slide = float(np.linalg.norm(settled.pos[:2] - planned.pos[:2]))
    if slide > MAX_SLIDE:
        return f"{name} slid {100 * slide:.1f} cm"
    return None


def _settle(text: str, objects: list[_Object], table: Table) -> tuple[list[_Object], str | None]:
    """The objects after physics brought them to rest, and why the layout failed (or None)."""
    model = mujoco.MjModel.from_xml_string(text)
    data = mujoco.MjData(model)
    dofs = _free_dofs(model, objects)
    rested, chunk = 0, 50
    for _ in range(round(SETTLE_S / model.opt.timestep) // chunk):
        mujoco.mj_step(model, data, chunk)
        rested = rested + 1 if data.time >= 0.2 and _at_rest(data, dofs) else 0
        if rested >= 2:
            break
    else:
        return objects, f"not at rest after {SETTLE_S:.0f} s"
    settled = [
        replace(o, pos=data.xpos[b].copy(), quat=data.xquat[b].copy())
        for o, (b, _) in zip(objects, dofs, strict=True)
    ]
    for planned, now in zip(objects, settled, strict=True):
        reason = _went_wrong(planned, now, table)
        if reason:
            return settled, reason
    return settled, None


def _stays_still(text: str, objects: list[_Object]) -> str | None:
    """Why the written scene is not usable as it is (overlap at start, objects moving)."""
    model = mujoco.MjModel.from_xml_string(text)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    deepest = min((c.dist for c in data.contact[: data.ncon]), default=0.0)
    if deepest < -OVERLAP:
        return f"objects overlap by {-1e3 * deepest:.1f} mm after settling"
    bodies = [b for b, _ in _free_dofs(model, objects)]
    start = data.xpos[bodies].copy()
    mujoco.mj_step(model, data, round(STILL_S / model.opt.timestep))
    moved = np.linalg.norm(data.xpos[bodies] - start, axis=1)
    if moved.max() > STILL_MOVE:
        return (
            f"{objects[int(moved.argmax())].name} moved {1e3 * moved.max():.1f} mm after settling"
        )
    return None


# -- the generator ------------------------------------------------------------------------------


def generate(seed: int, shelf: bool = False) -> GeneratedScene:
    """A random table-top scene, settled; raises ``GenerationError`` when no layout settles as
    planned in ``MAX_ATTEMPTS`` draws. ``shelf``: an open shelf with a stack on its upper board
    instead of a table (its body is named ``table`` too: the support graph reads alike)."""
    rng = np.random.default_rng(seed)
    table = draw_shelf(rng) if shelf else draw_table(rng)
    robot_start = draw_robot_start(rng, table)
    rejected: list[str] = []
    for _ in range(MAX_ATTEMPTS):
        objects, arrangements = _draw_layout(rng, table, robot_start)
        if len(objects) < 3:
            rejected.append(f"only {len(objects)} objects fit")
            continue
        planned = _mjcf(seed, table, robot_start, objects, arrangements)
        settled, reason = _settle(planned, objects, table)
        text = _mjcf(seed, table, robot_start, settled, arrangements)
        reason = reason or _stays_still(text, settled)
        if reason:
            rejected.append(reason)
            continue
        return GeneratedScene(seed, text, table, robot_start, tuple(arrangements), tuple(rejected))
    raise GenerationError(
        f"seed {seed}: no layout settled as planned in {MAX_ATTEMPTS} attempts "
        f"(last: {rejected[-1]})"
    )


def generate_scene(seed: int, shelf: bool = False) -> str:
    """The MJCF text of ``generate(seed, shelf)``."""
    return generate(seed, shelf).text
