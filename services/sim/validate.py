"""Check a scene file the way the sim will use it: every problem as one line.

Problems: the file does not load (the sim's ``SceneError``), no ``robot_start`` or ``roi`` site,
bodies interpenetrating at start (the robot at robot_start included), objects not at rest
(moving more than 1 cm or turning more than 2° in 1 s of physics without the robot), objects
outside the roi, a roi with no object in it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from services.sim.ground_truth import geom_half_extents
from services.sim.robots import BASE_JOINTS, ROBOTS, RobotInfo
from services.sim.scene import (
    PENETRATION_TOLERANCE,
    ROBOT_PREFIX,
    SceneError,
    _check_objects,
    _compile,
    _load_spec,
    load_world_model,
    owner_name,
    resolve_scene,
)

STILL_S = 1.0  # s of physics an object must stay at rest for
MOVE_TOLERANCE = 0.01  # m
TURN_TOLERANCE = math.radians(2.0)
ROI_TOLERANCE = 0.01  # m an object may stick out of the roi


@dataclass(frozen=True)
class Validation:
    """The problems of a scene file; ``loads`` is False when the sim cannot load it at all."""

    path: Path
    loads: bool
    problems: tuple[str, ...]


def validate_scene(path: str | Path, robot: str = "armar6") -> list[str]:
    """Every problem of the scene file, one line each; empty when it is fine."""
    return list(check_scene(path, robot).problems)


def check_scene(path: str | Path, robot: str = "armar6") -> Validation:
    """Validate ``path`` with ``robot`` (a name in ``ROBOTS``) standing at robot_start."""
    try:
        path = resolve_scene(path)
        alone = _load_alone(path)
        sites = {alone.site(i).name for i in range(alone.nsite)}
        model, data = (
            _with_robot(path, ROBOTS[robot]) if "robot_start" in sites else _at_start(alone)
        )
    except SceneError as e:
        return Validation(Path(path), False, (str(e),))
    problems = []
    if "robot_start" not in sites:
        problems.append("no robot_start site: the sim does not know where to put the robot")
    problems += _overlaps(model, data)
    problems += _roi_problems(*_at_start(alone), "roi" in sites)
    problems += _moving(alone)
    return Validation(path, True, tuple(str(SceneError(path, p)) for p in problems))


# -- loading ------------------------------------------------------------------------------------


def _load_alone(path: Path) -> mujoco.MjModel:
    """The scene without the robot, compiled as the sim does (same checks, same errors)."""
    spec = _load_spec(path)
    _check_objects(path, spec)
    model = _compile(path, spec)
    model.opt.timestep = 0.001
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    return model


def _at_start(model: mujoco.MjModel) -> tuple[mujoco.MjModel, mujoco.MjData]:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    return model, data


def _with_robot(path: Path, robot: RobotInfo) -> tuple[mujoco.MjModel, mujoco.MjData]:
    """The scene with the robot at robot_start in its home pose, as the sim starts it."""
    model, info = load_world_model(path, robot)
    data = mujoco.MjData(model)
    for name, value in zip(BASE_JOINTS, info.robot_start, strict=True):
        data.qpos[model.joint(ROBOT_PREFIX + name).qposadr[0]] = value
    for name, value in robot.home.items():
        joint = model.joint(ROBOT_PREFIX + name)
        lo, hi = joint.range if joint.limited[0] else (-math.inf, math.inf)
        data.qpos[joint.qposadr[0]] = min(max(value, lo), hi)
    mujoco.mj_forward(model, data)
    return model, data


# -- checks -------------------------------------------------------------------------------------


def _overlaps(model: mujoco.MjModel, data: mujoco.MjData) -> list[str]:
    """Every pair of bodies interpenetrating by more than 1 mm, deepest first."""
    deepest: dict[tuple[str, str], float] = {}
    for c in data.contact[: data.ncon]:
        if c.dist >= -PENETRATION_TOLERANCE:
            continue
        a, b = (owner_name(model, int(g)) or f"geom {int(g)}" for g in c.geom)
        pair = (b, a) if a == "robot" else (a, b)
        deepest[pair] = max(deepest.get(pair, 0.0), -float(c.dist))
    problems = []
    for (a, b), depth in sorted(deepest.items(), key=lambda item: -item[1]):
        if b == "robot":
            problems.append(f"the robot at robot_start overlaps {a!r} by {depth * 1e3:.1f} mm")
        else:
            problems.append(
                f"objects start interpenetrating: {a!r} and {b!r} by {depth * 1e3:.1f} mm"
            )
    return problems


def _objects(model: mujoco.MjModel) -> dict[str, int]:
    """Free bodies (the scene's objects): name → body id."""
    return {
        model.body(b).name: b
        for b in range(1, model.nbody)
        if model.body_jntnum[b]
        and model.jnt_type[model.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE
    }


def _object_boxes(
    model: mujoco.MjModel, data: mujoco.MjData
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each object's world axis-aligned bounding box (min corner, max corner)."""
    objects = _objects(model)
    boxes = {n: (np.full(3, np.inf), np.full(3, -np.inf)) for n in objects}
    for g in range(model.ngeom):
        name = owner_name(model, g)
        if name not in boxes:
            continue
        reach = np.abs(data.geom_xmat[g].reshape(3, 3)) @ geom_half_extents(model, g)
        lo, hi = boxes[name]
        boxes[name] = (
            np.minimum(lo, data.geom_xpos[g] - reach),
            np.maximum(hi, data.geom_xpos[g] + reach),
        )
    return boxes


def _roi_problems(model: mujoco.MjModel, data: mujoco.MjData, has_roi: bool) -> list[str]:
    """A missing roi, objects outside it, a roi with no object in it."""
    if not has_roi:
        return ["no roi site: nothing marks the region of interest (a box site named roi)"]
    i = model.site("roi").id
    if model.site_type[i] != mujoco.mjtGeom.mjGEOM_BOX:
        return ["site roi must be a box (type='box' with size = half extents)"]
    roi_lo, roi_hi = data.site_xpos[i] - model.site_size[i], data.site_xpos[i] + model.site_size[i]
    problems, inside = [], 0
    for name, (lo, hi) in _object_boxes(model, data).items():
        centre = (lo + hi) / 2
        if np.any(centre < roi_lo) or np.any(centre > roi_hi):
            problems.append(f"object {name!r} is outside the roi")
            continue
        inside += 1
        out = max(float(np.max(roi_lo - lo)), float(np.max(hi - roi_hi)))
        if out > ROI_TOLERANCE:
            problems.append(f"object {name!r} sticks out of the roi by {out * 100:.1f} cm")
    if not inside:
        problems.append("roi contains no object")
    return problems


def _turned(q0: np.ndarray, q1: np.ndarray) -> float:
    return 2 * math.acos(min(1.0, abs(float(np.dot(q0, q1)))))


def _moving(model: mujoco.MjModel) -> list[str]:
    """Objects that do not stay put for 1 s of physics (robot left out)."""
    model, data = _at_start(model)
    objects = _objects(model)
    start = {n: (data.xpos[b].copy(), data.xquat[b].copy()) for n, b in objects.items()}
    mujoco.mj_step(model, data, round(STILL_S / model.opt.timestep))
    problems = []
    for name, b in objects.items():
        moved = float(np.linalg.norm(data.xpos[b] - start[name][0]))
        turned = _turned(start[name][1], data.xquat[b])
        if moved > MOVE_TOLERANCE or turned > TURN_TOLERANCE:
            problems.append(
                f"object {name!r} is not at rest: it moved {moved * 100:.1f} cm and turned "
                f"{math.degrees(turned):.1f}° in {STILL_S:.0f} s"
            )
    return problems
