"""Scene files: find them, check them, and merge the robot in at ``robot_start``.

A scene is an MJCF file. Its worldbody holds static geoms and bodies (floor, tables, walls) and
free bodies (objects, each made of box, cylinder and sphere geoms). It must have a site
``robot_start`` (position and yaw of the robot); it may have a box site ``roi`` (the region whose
unknown voxels are counted), a box site ``workspace`` (where the platform may go, e.g. inside
a booth's walls) and sites ``poi_*`` (points of interest). Every problem is reported
as one ``SceneError`` line that names the file.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from services.sim.robots import BASE_JOINTS, RobotInfo

SCENES_DIR = Path(__file__).parent / "scenes"
BUILTIN_SCENES = tuple(sorted(p.stem for p in SCENES_DIR.glob("*.xml")))
ROBOT_PREFIX = "robot/"
OBJECT_GEOMS = {
    mujoco.mjtGeom.mjGEOM_BOX: "box",
    mujoco.mjtGeom.mjGEOM_CYLINDER: "cylinder",
    mujoco.mjtGeom.mjGEOM_SPHERE: "sphere",
}
#: deepest overlap of two bodies tolerated at the start (m)
PENETRATION_TOLERANCE = 1e-3


class SceneError(ValueError):
    """A scene file that cannot be used, with the file and the problem in one line."""

    def __init__(self, path: Path | str, problem: str) -> None:
        super().__init__(f"scene file {path}: {problem}")
        self.path = Path(path)
        self.problem = problem


@dataclass
class SceneInfo:
    """What the rest of the sim needs to know about a loaded scene."""

    name: str
    path: Path
    robot_start: tuple[float, float, float]  # x, y, yaw
    robot_start_z: float
    roi: tuple[np.ndarray, np.ndarray] | None  # (min corner, max corner)
    workspace: tuple[np.ndarray, np.ndarray] | None = None  # where the platform may go (x, y)
    pois: dict[str, np.ndarray] = field(default_factory=dict)
    objects: list[str] = field(default_factory=list)  # free bodies
    statics: list[str] = field(default_factory=list)  # named static bodies and world geoms

    @property
    def vertices(self) -> list[str]:
        """The support graph's vertices: every named static part and object."""
        return self.statics + self.objects


def resolve_scene(name_or_file: str | Path) -> Path:
    """A built-in scene's file, or the given file."""
    text = str(name_or_file)
    if text in BUILTIN_SCENES:
        return SCENES_DIR / f"{text}.xml"
    path = Path(text)
    if path.suffix == "" and not path.exists():
        raise SceneError(path, f"no such built-in scene (built-ins: {', '.join(BUILTIN_SCENES)})")
    if not path.is_file():
        raise SceneError(path, "no such file")
    return path


def _first_line(error: Exception) -> str:
    return str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__


def _load_spec(path: Path) -> mujoco.MjSpec:
    try:
        return mujoco.MjSpec.from_file(str(path))
    except Exception as e:
        raise SceneError(path, f"not a valid MuJoCo MJCF file ({_first_line(e)})") from None


def _is_free(body: mujoco.MjsBody) -> bool:
    return any(j.type == mujoco.mjtJoint.mjJNT_FREE for j in body.joints)


def _body_geoms(body: mujoco.MjsBody) -> list[mujoco.MjsGeom]:
    """Geoms of a body and of its joint-less descendants (they move with it)."""
    geoms = list(body.geoms)
    for child in body.bodies:
        if not child.joints:
            geoms += _body_geoms(child)
    return geoms


def _check_objects(path: Path, spec: mujoco.MjSpec) -> None:
    for body in spec.bodies:
        if not _is_free(body):
            continue
        where = f"free body {body.name!r}" if body.name else f"a free body at {list(body.pos)}"
        if not body.name:
            raise SceneError(path, f"{where} has no name (objects need one)")
        geoms = _body_geoms(body)
        if not geoms:
            raise SceneError(path, f"{where} has no geom")
        for geom in geoms:
            if geom.type not in OBJECT_GEOMS:
                kind = mujoco.mjtGeom(geom.type).name.removeprefix("mjGEOM_").lower()
                raise SceneError(
                    path,
                    f"{where} has a {kind} geom; objects are made of box, cylinder and "
                    "sphere geoms",
                )


def _compile(path: Path, spec: mujoco.MjSpec) -> mujoco.MjModel:
    try:
        return spec.compile()
    except Exception as e:
        raise SceneError(path, f"does not compile ({_first_line(e)})") from None


def _site_yaw(xmat: np.ndarray) -> float:
    R = xmat.reshape(3, 3)
    return math.atan2(R[1, 0], R[0, 0])


def _scene_facts(path: Path, model: mujoco.MjModel) -> SceneInfo:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    names = [model.site(i).name for i in range(model.nsite)]
    if "robot_start" not in names:
        raise SceneError(path, "has no site named robot_start (where the robot stands)")
    start = names.index("robot_start")
    x, y, z = data.site_xpos[start]
    boxes = {}
    for box in ("roi", "workspace"):
        if box in names:
            i = names.index(box)
            half = model.site_size[i]
            if model.site_type[i] != mujoco.mjtGeom.mjGEOM_BOX:
                raise SceneError(
                    path, f"site {box} must be a box (type='box' with size = half extents)"
                )
            boxes[box] = (data.site_xpos[i] - half, data.site_xpos[i] + half)
    roi = boxes.get("roi")
    pois = {n: data.site_xpos[i].copy() for i, n in enumerate(names) if n.startswith("poi_")}
    objects, statics = vertices(model)
    return SceneInfo(
        name=path.stem,
        path=path,
        robot_start=(float(x), float(y), _site_yaw(data.site_xmat[start])),
        robot_start_z=float(z),
        roi=roi,
        workspace=boxes.get("workspace"),
        pois=pois,
        objects=objects,
        statics=statics,
    )


def _visible(model: mujoco.MjModel, geom: int) -> bool:
    """Drawn by a camera: in a default-visible group (0-2) and not fully transparent."""
    return model.geom_group[geom] < 3 and model.geom_rgba[geom][3] > 0


def vertices(model: mujoco.MjModel) -> tuple[list[str], list[str]]:
    """(objects, statics): the free bodies, and the static parts (visible world geoms, then
    static bodies below the world), each by the name ``owner_name`` gives it. The robot's
    bodies are neither."""
    objects, statics = [], []
    has_geoms = set(model.body_rootid[model.geom_bodyid].tolist())
    for b in range(1, model.nbody):
        name = model.body(b).name
        if name.startswith(ROBOT_PREFIX) or model.body_parentid[b] != 0:
            continue
        if model.body_weldid[b] == 0:
            if b in has_geoms:
                statics.append(name or f"body_{b}")
        elif (
            model.body_jntnum[b]
            and model.jnt_type[model.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE
        ):
            objects.append(name)
    world = [
        owner_name(model, g)
        for g in range(model.ngeom)
        if model.geom_bodyid[g] == 0 and _visible(model, g)
    ]
    return objects, world + statics


def load_world_model(
    scene: str | Path,
    robot: RobotInfo,
    *,
    timestep: float = 0.001,
    offscreen: tuple[int, int] = (1280, 960),
) -> tuple[mujoco.MjModel, SceneInfo]:
    """Compile ``scene`` with ``robot`` attached at the world origin (its base joints then hold
    world x, y, yaw; the sim sets them to robot_start). Raises ``SceneError``."""
    path = resolve_scene(scene)
    spec = _load_spec(path)
    _check_objects(path, spec)
    info = _scene_facts(path, _compile(path, spec))

    robot_spec = mujoco.MjSpec.from_file(str(robot.mjcf))
    frame = spec.worldbody.add_frame(pos=[0.0, 0.0, info.robot_start_z])
    frame.attach_body(robot_spec.body("base"), ROBOT_PREFIX, "")
    spec.option.timestep = timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # no multisampling: one render pass then gives per-pixel exact depth and segmentation that
    # match the colour image (with MSAA, edge pixels resolve to mixtures of both sides)
    spec.visual.quality.offsamples = 0
    spec.visual.global_.offwidth = max(offscreen[0], spec.visual.global_.offwidth)
    spec.visual.global_.offheight = max(offscreen[1], spec.visual.global_.offheight)
    model = _compile(path, spec)
    info.objects, info.statics = vertices(model)
    return model, info


def robot_joint_names(model: mujoco.MjModel) -> list[str]:
    """The robot's joints (prefix stripped), base joints first."""
    names = [
        model.joint(j).name.removeprefix(ROBOT_PREFIX)
        for j in range(model.njnt)
        if model.joint(j).name.startswith(ROBOT_PREFIX)
    ]
    base = [n for n in BASE_JOINTS if n in names]
    return base + [n for n in names if n not in BASE_JOINTS]


def owner_name(model: mujoco.MjModel, geom: int) -> str:
    """The name a geom answers to in the ground truth: its top body below the world (the
    object or static body it belongs to), its own name for world geoms, 'robot' for the
    robot's geoms. Unnamed world geoms and static bodies are ``geom_<id>`` and ``body_<id>``,
    so that a scene needs no names for its furniture."""
    body = int(model.geom_bodyid[geom])
    if body == 0:
        return model.geom(geom).name or f"geom_{geom}"
    body = int(model.body_rootid[body])
    name = model.body(body).name
    if name.startswith(ROBOT_PREFIX):
        return "robot"
    return name or f"body_{body}"


def body_id(model: mujoco.MjModel, name: str) -> int:
    """The id of the body ``owner_name`` calls ``name``."""
    try:
        return model.body(name).id
    except KeyError:
        if name.startswith("body_") and name[5:].isdigit():
            return int(name[5:])
        raise


def check_start_overlaps(path: Path, model: mujoco.MjModel, data: mujoco.MjData) -> None:
    """Refuse bodies that start interpenetrating (deeper than 1 mm)."""
    mujoco.mj_forward(model, data)
    for c in data.contact[: data.ncon]:
        if c.dist < -PENETRATION_TOLERANCE:
            a, b = owner_name(model, c.geom[0]), owner_name(model, c.geom[1])
            a = a or f"geom {c.geom[0]}"
            b = b or f"geom {c.geom[1]}"
            if "robot" in (a, b):
                other = b if a == "robot" else a
                problem = f"the robot at robot_start overlaps {other!r}"
            else:
                problem = f"objects start interpenetrating: {a!r} and {b!r}"
            raise SceneError(path, f"{problem} by {-c.dist * 1e3:.1f} mm")
