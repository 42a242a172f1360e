"""Generated scenes: they validate, load with armar6 and rest; table, objects, robot start and roi
are within the promised ranges; the ground-truth support graph is the planned one. The
validator finds each kind of broken scene; the CLI writes and checks a scene."""

from __future__ import annotations

import itertools
import math
import re
import subprocess
import sys
import xml.etree.ElementTree as ET

import mujoco
import numpy as np
import pytest

from services.sim import generate as gen
from services.sim.generate import GenerationError, generate, generate_scene, heading_offset
from services.sim.ground_truth import support_graph
from services.sim.robots import ROBOTS
from services.sim.validate import check_scene, validate_scene
from services.sim.world import World
from tests.conftest import ROOT

#: between them every kind of arrangement (checked below)
SEEDS = (0, 2, 3, 5, 14)
KINDS = {"single", "stack", "bridge", "hidden", "touching"}


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """seed → (GeneratedScene, its file, World loaded from the file)."""
    out = {}
    directory = tmp_path_factory.mktemp("generated")
    for seed in SEEDS:
        scene = generate(seed)
        path = directory / f"seed_{seed}.xml"
        path.write_text(scene.text)
        out[seed] = (scene, path, World(path, ROBOTS["armar6"]))
    return out


def _objects(world: World) -> dict[str, int]:
    """Object name → its (single) geom id."""
    m = world.model
    return {n: int(m.body_geomadr[m.body(n).id]) for n in world.info.objects}


def _half_extents(model: mujoco.MjModel, g: int) -> np.ndarray:
    s = model.geom_size[g]
    kind = model.geom_type[g]
    if kind == mujoco.mjtGeom.mjGEOM_BOX:
        return s.copy()
    return np.array([s[0], s[0], s[1]] if kind == mujoco.mjtGeom.mjGEOM_CYLINDER else [s[0]] * 3)


def _table_top(world: World) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, rotation, half extents) of the table top."""
    g = world.model.geom("table_top").id
    return (
        world.data.geom_xpos[g].copy(),
        world.data.geom_xmat[g].reshape(3, 3).copy(),
        world.model.geom_size[g].copy(),
    )


def _distance_to_footprint(world: World, xy: np.ndarray) -> float:
    centre, R, half = _table_top(world)
    local = R[:2, :2].T @ (xy - centre[:2])
    return float(np.linalg.norm(np.maximum(np.abs(local) - half[:2], 0.0)))


# -- generated scenes -------------------------------------------------------------------------


def test_the_seeds_cover_every_arrangement(scenes):
    kinds = {a.kind for scene, _, _ in scenes.values() for a in scene.arrangements}
    assert kinds == KINDS


@pytest.mark.parametrize("seed", SEEDS)
def test_scene_validates_loads_and_rests(scenes, seed):
    scene, path, world = scenes[seed]
    assert validate_scene(path) == []
    assert 3 <= len(world.info.objects) <= 8
    assert sorted(world.info.objects) == sorted(scene.objects)
    assert len(set(scene.objects)) == len(scene.objects)
    bodies = [world.model.body(n).id for n in world.info.objects]
    start = world.data.xpos[bodies].copy()
    world.step(1000)
    moved = np.linalg.norm(world.data.xpos[bodies] - start, axis=1)
    assert moved.max() < 1e-3
    world.reset()


@pytest.mark.parametrize("seed", SEEDS)
def test_sites_have_default_styling_and_the_header_lists_the_arrangements(scenes, seed):
    scene, path, _ = scenes[seed]
    root = ET.parse(path).getroot()
    sites = {s.get("name"): s.attrib for s in root.iter("site")}
    assert set(sites) == {"robot_start", "roi"}
    for attributes in sites.values():
        assert not {"rgba", "group"} & set(attributes)
    header = scene.text.split("-->")[0]
    assert f"seed {seed}" in header
    for arrangement in scene.arrangements:
        assert f"    {arrangement}\n" in header


def test_same_seed_same_text_other_seeds_other_scenes(scenes):
    assert generate_scene(SEEDS[0]) == scenes[SEEDS[0]][0].text
    texts = [scene.text for scene, _, _ in scenes.values()]
    assert len(set(texts)) == len(texts)


@pytest.mark.parametrize("seed", SEEDS)
def test_table_and_objects_are_within_range(scenes, seed):
    _, _, world = scenes[seed]
    centre, R, half = _table_top(world)
    top = centre[2] + half[2]
    assert 0.6 <= 2 * half[0] <= 1.6 and 0.5 <= 2 * half[1] <= 1.0
    assert 0.03 <= 2 * half[2] <= 0.05 and 0.6 <= top <= 0.9
    assert 1.0 <= np.linalg.norm(centre[:2]) <= 2.0
    m, d = world.model, world.data
    for name, g in _objects(world).items():
        extents = _half_extents(m, g)
        assert extents.min() >= 0.02 and extents.max() <= 0.15, name
        if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
            assert 0.03 <= extents[0] <= 0.08
        # on the table top, at least 3 cm inside its edges (1 mm for settling)
        Rg = d.geom_xmat[g].reshape(3, 3)
        reach = np.abs(R.T @ Rg) @ extents  # extent along the table's axes
        offset = np.abs(R.T @ (d.geom_xpos[g] - centre))
        assert np.all(offset[:2] + reach[:2] <= half[:2] - 0.03 + 1e-3), name
        assert d.geom_xpos[g][2] - reach[2] >= top - 1e-3, name


@pytest.mark.parametrize("seed", SEEDS)
def test_object_colours_are_distinct(scenes, seed):
    _, path, _ = scenes[seed]
    root = ET.parse(path).getroot()
    textures = {t.get("name"): t.get("rgb1") for t in root.iter("texture")}
    materials = {m.get("name"): textures[m.get("texture")] for m in root.iter("material")}
    colours = []
    for body in root.iter("body"):
        if body.find("freejoint") is None:
            continue
        geom = body.find("geom")
        rgb = geom.get("rgba") or materials[geom.get("material")]
        colours.append(np.array(rgb.split()[:3], dtype=float))
    distances = [np.linalg.norm(a - b) for a, b in itertools.combinations(colours, 2)]
    assert min(distances) >= 0.3


@pytest.mark.parametrize("seed", SEEDS)
def test_robot_start_is_near_the_table_and_clear_of_it(scenes, seed):
    scene, _, world = scenes[seed]
    x, y, yaw = world.info.robot_start
    assert world.info.robot_start_z == 0.0
    assert 0.5 <= _distance_to_footprint(world, np.array([x, y])) <= 2.5
    assert (x, y, yaw) == pytest.approx(scene.robot_start, abs=1e-5)


@pytest.mark.parametrize("seed", SEEDS)
def test_roi_covers_the_table_top_and_the_objects(scenes, seed):
    _, _, world = scenes[seed]
    lo, hi = world.info.roi
    centre, R, half = _table_top(world)
    corners = [
        centre[:2] + R[:2, :2] @ (half[:2] * s) for s in ((1, 1), (1, -1), (-1, 1), (-1, -1))
    ]
    aabb = np.min(corners, axis=0), np.max(corners, axis=0)
    assert lo[:2] == pytest.approx(aabb[0] - 0.05, abs=1e-4)
    assert hi[:2] == pytest.approx(aabb[1] + 0.05, abs=1e-4)
    assert lo[2] == pytest.approx(centre[2] + half[2] - 0.03, abs=1e-4)
    m, d = world.model, world.data
    tops = [
        d.geom_xpos[g][2] + np.abs(d.geom_xmat[g].reshape(3, 3))[2] @ _half_extents(m, g)
        for g in _objects(world).values()
    ]
    assert hi[2] == pytest.approx(max(tops) + 0.1, abs=2e-3)


def test_robot_starts_within_range_and_one_in_four_faces_away():
    offsets = []
    for seed in range(40):
        scene = generate(seed)
        assert 0.5 <= scene.table.distance(np.array(scene.robot_start[:2])) <= 2.5
        offsets.append(math.degrees(heading_offset(scene.robot_start, scene.table)))
    away = sum(o > 100 for o in offsets)
    assert 4 <= away <= 16, offsets
    assert all(o <= 40 + 1e-6 for o in offsets if o <= 100)


@pytest.mark.parametrize("seed", SEEDS)
def test_ground_truth_support_graph_is_the_planned_one(scenes, seed):
    scene, _, world = scenes[seed]
    edges, closure = support_graph(world.model, world.data, world.info)
    edges = set(edges)
    for arrangement in scene.arrangements:
        for name in arrangement.on_table:
            assert ("table", name) in edges
        if arrangement.kind == "stack":
            bottom, top = arrangement.objects
            assert (bottom, top) in edges and ("table", top) not in edges
        if arrangement.kind == "bridge":
            first, second, plank = arrangement.objects
            assert {(first, plank), (second, plank)} <= edges
    assert edges == scene.support_edges
    assert {("table", name) for name in scene.objects} <= set(closure)


def test_a_layout_that_does_not_settle_is_redrawn_then_given_up(monkeypatch):
    def overhanging_stack(rng):
        bottom = gen._Part("box", "box", (0.05, 0.05, 0.05))
        top = gen._Part("box", "box", (0.05, 0.05, 0.05), u=0.08, bottom=bottom.top + gen.DROP)
        return [bottom, top]

    monkeypatch.setattr(gen, "ARRANGEMENTS", {"stack": (2, overhanging_stack, 1.0)})
    monkeypatch.setattr(gen, "MAX_ATTEMPTS", 3)
    with pytest.raises(GenerationError, match=r"seed 1: .* 3 attempts .*(toppled|fell|slid|sank)"):
        generate(1)


# -- the validator --------------------------------------------------------------------------

TABLE = '<body name="table"><geom type="box" size=".4 .4 .375" pos="1.5 0 .375"/></body>'
ON_TABLE = 0.751  # 1 mm above the table's top


def _scene(tmp_path, objects: str, *, start: str = "0 0 0", roi: str | None = None) -> str:
    """A small scene: floor, table, robot_start, roi over the table, ``objects``."""
    roi = (
        roi if roi is not None else '<site name="roi" type="box" pos="1.5 0 .9" size=".45 .45 .2"/>'
    )
    start_site = f'<site name="robot_start" pos="{start}"/>' if start else ""
    path = tmp_path / "scene.xml"
    path.write_text(
        '<mujoco><option timestep="0.001"/><worldbody>'
        '<geom name="floor" type="plane" size="5 5 .1"/>'
        f"{TABLE}{start_site}{roi}{objects}</worldbody></mujoco>"
    )
    return str(path)


def _box(name: str, x: float, y: float = 0.0, z: float = ON_TABLE + 0.05) -> str:
    geom = '<geom type="box" size=".05 .05 .05"/>'
    return f'<body name="{name}" pos="{x} {y} {z}"><freejoint/>{geom}</body>'


def test_validator_passes_the_plain_scene(tmp_path):
    assert validate_scene(_scene(tmp_path, _box("a", 1.4) + _box("b", 1.6))) == []


def test_validator_names_every_interpenetrating_pair(tmp_path):
    path = _scene(tmp_path, _box("a", 1.3) + _box("b", 1.38) + _box("c", 1.7) + _box("d", 1.79))
    problems = [p for p in validate_scene(path) if "interpenetrating" in p]
    depths = {
        (m[1], m[2]): float(m[3])
        for m in (re.search(r"'(\w)' and '(\w)' by ([\d.]+) mm", p) for p in problems)
    }
    assert depths == {("a", "b"): pytest.approx(20, abs=1), ("c", "d"): pytest.approx(10, abs=1)}
    assert all(path in p for p in problems)


def test_validator_finds_a_floating_object(tmp_path):
    problems = validate_scene(_scene(tmp_path, _box("a", 1.4) + _box("floater", 1.6, z=1.0)))
    assert len(problems) == 1
    moved = re.search(r"object 'floater' is not at rest: it moved ([\d.]+) cm", problems[0])
    assert moved and float(moved[1]) > 10


def test_validator_finds_a_missing_roi_and_a_roi_without_objects(tmp_path):
    objects = _box("a", 1.4) + _box("b", 1.6)
    problems = validate_scene(_scene(tmp_path, objects, roi=""))
    assert len(problems) == 1 and "no roi site" in problems[0]
    away = '<site name="roi" type="box" pos="-2 -2 .5" size=".3 .3 .3"/>'
    problems = validate_scene(_scene(tmp_path, objects, roi=away))
    assert any(p.endswith("roi contains no object") for p in problems)
    assert sum("is outside the roi" in p for p in problems) == 2


def test_validator_finds_the_robot_in_the_table_and_a_missing_start(tmp_path):
    problems = validate_scene(_scene(tmp_path, _box("a", 1.4), start="1.2 0 0"))
    assert len(problems) == 1 and "the robot at robot_start overlaps 'table' by" in problems[0]
    problems = validate_scene(_scene(tmp_path, _box("a", 1.4), start=""))
    assert len(problems) == 1 and "no robot_start site" in problems[0]


def test_validator_reports_a_file_that_does_not_load(tmp_path):
    path = tmp_path / "broken.xml"
    path.write_text("this is not xml <")
    result = check_scene(path)
    assert not result.loads
    assert len(result.problems) == 1 and "not a valid MuJoCo MJCF file" in result.problems[0]


# -- the command line -------------------------------------------------------------------------


def _avs(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "avs.cli", "scene", *args],
        capture_output=True,
        text=True,
        timeout=120,
        cwd=ROOT,
    )


def test_cli_generates_a_scene_that_validates(tmp_path):
    path = tmp_path / "new" / "scene.xml"
    out = _avs("generate", "--seed", "3", "--out", str(path))
    assert out.returncode == 0, out.stderr
    assert out.stdout.count("\n") == 1 and str(path) in out.stdout and "hidden:" in out.stdout
    assert path.read_text() == generate_scene(3)
    out = _avs("validate", str(path))
    assert out.returncode == 0, out.stdout + out.stderr
    assert out.stdout.strip() == f"{path}: ok"


def test_cli_refuses_a_scene_file_name_mujoco_would_not_load(tmp_path):
    path = tmp_path / "scene"
    out = _avs("generate", "--seed", "3", "--out", str(path))
    assert out.returncode == 2 and not path.exists()
    assert len(out.stderr.strip().splitlines()) == 1 and "must end in .xml" in out.stderr


def test_cli_validate_exit_codes(tmp_path):
    bad = _scene(tmp_path, _box("a", 1.4) + _box("b", 1.45))
    out = _avs("validate", bad)
    assert out.returncode == 1
    assert out.stdout.splitlines() == validate_scene(bad) and "'a' and 'b'" in out.stdout
    out = _avs("validate", str(tmp_path / "missing.xml"))
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "no such file" in out.stderr


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_generated_shelf_holds_a_stack_on_its_upper_board(seed, tmp_path):
    """``generate(seed, shelf=True)``: an open shelf (two boards between two side panels, its
    body named ``table``), a stack and 0-2 single objects on the upper board, all at rest;
    the sim's support graph is the planned one (floor → shelf → bottom of the stack → top),
    and nothing rests on the lower board or the floor."""
    scene = generate(seed, shelf=True)
    assert scene.table.kind == "shelf" and scene.arrangements[0].kind == "stack"
    assert {a.kind for a in scene.arrangements[1:]} <= {"single"}
    assert 0.85 <= scene.table.height <= 1.05 and 0.35 <= scene.table.lower <= 0.5
    path = tmp_path / "shelf.xml"
    path.write_text(scene.text)
    assert validate_scene(path) == []
    root = ET.parse(path).getroot()
    shelf = next(b for b in root.iter("body") if b.get("name") == "table")
    names = [g.get("name") for g in shelf.iter("geom")]
    assert names.count("board_low") == 1 and names.count("table_top") == 1 and len(names) == 4
    world = World(path, ROBOTS["armar6"])
    bodies = [world.model.body(n).id for n in world.info.objects]
    assert np.all(world.data.xpos[bodies][:, 2] > scene.table.height)  # all on the upper board
    start = world.data.xpos[bodies].copy()
    world.step(1000)
    assert np.linalg.norm(world.data.xpos[bodies] - start, axis=1).max() < 1e-3
    edges, _ = support_graph(world.model, world.data, world.info)
    assert set(edges) == scene.support_edges
    bottom, top = scene.arrangements[0].objects
    assert {("table", bottom), (bottom, top)} <= set(edges)
