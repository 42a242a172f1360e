"""Affordances from primitive geometry and the robot's hands (thesis 3.2.3).

An affordance maps end-effector poses x ∈ SE(3) to a belief; here each one carries sampled
poses T_world_hand and a confidence. Hand frame: z is the approach direction (from the palm
into the object), y the direction the fingers close along, x = y × z.

- grasp: cylinders and spheres that fit the hand, boxes with a side that fits it;
- lift: boxes too wide for one hand but not for two (bimanual, a pose per hand);
- push: objects resting on a surface, pushed horizontally from the robot's side;
- support: level surfaces (planes, box tops) large enough to lean a hand on, palm down;
- lean: vertical planes (walls, cupboard fronts), palm against them;
- hold: long, thin primitives (bars, bottles, handles) held in a power grasp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from services.perception.obb import cross
from services.perception.primitives import Extracted
from services.perception.relations import RelationConfig, top_area

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class Hand:
    """ARMAR hands, roughly: widest and narrowest graspable size, shoulder width (m)."""

    max_grasp: float = 0.10
    min_grasp: float = 0.015
    shoulder_width: float = 0.6
    min_support_area: float = 0.04


@dataclass
class AffordanceOut:
    kind: str
    primitive: int
    poses: np.ndarray  # (k, 4, 4)
    confidence: float
    bimanual: bool = False


def _pose(approach: np.ndarray, closing: np.ndarray, position: np.ndarray) -> np.ndarray:
    z = approach / np.linalg.norm(approach)
    y = closing - (closing @ z) * z
    n = np.linalg.norm(y)
    y = y / n if n > 1e-9 else cross(z, [1.0, 0, 0] if abs(z[0]) < 0.9 else [0, 1.0, 0])
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([cross(y, z), y, z])
    T[:3, 3] = position
    return T


def _horizontal_towards(target: np.ndarray, viewer: np.ndarray) -> np.ndarray:
    d = target - viewer
    d[2] = 0
    n = np.linalg.norm(d)
    return d / n if n > 1e-9 else np.array([1.0, 0, 0])


def affordances(
    prims: list[Extracted], viewer: np.ndarray, resting: set[int], hand: Hand | None = None
) -> list[AffordanceOut]:
    """Affordances of every primitive; ``viewer`` is where the robot looks from (approach
    directions come from its side), ``resting`` the primitives supported by something."""
    hand = hand or Hand()
    out: list[AffordanceOut] = []
    for i, p in enumerate(prims):
        toward = _horizontal_towards(p.box.center, viewer)
        side = cross(UP, toward)
        if p.kind == "cylinder":
            width = 2 * p.radius
            if hand.min_grasp <= width <= hand.max_grasp:
                closing = cross(p.axis, toward)
                fit = 1 - abs(width - 0.6 * hand.max_grasp) / hand.max_grasp
                out.append(
                    AffordanceOut(
                        "grasp",
                        i,
                        _pose(toward, closing, p.center)[None],
                        float(np.clip(fit, 0.3, 1)),
                    )
                )
                if p.height >= 2 * width:
                    out.append(
                        AffordanceOut(
                            "hold",
                            i,
                            _pose(toward, closing, p.center)[None],
                            float(np.clip(p.height / (4 * width), 0.3, 1)),
                        )
                    )
        elif p.kind == "sphere":
            width = 2 * p.radius
            if hand.min_grasp <= width <= hand.max_grasp:
                out.append(AffordanceOut("grasp", i, _pose(toward, side, p.center)[None], 0.8))
        elif p.kind == "box":
            R, ext = p.rotation, p.extent
            horizontal = [k for k in range(3) if abs(R[2, k]) < 0.5]
            narrow = [k for k in horizontal if hand.min_grasp <= ext[k] <= hand.max_grasp]
            if narrow:
                k = min(narrow, key=lambda k: ext[k])
                out.append(
                    AffordanceOut(
                        "grasp",
                        i,
                        _pose(toward, R[:, k], p.center)[None],
                        float(np.clip(1 - ext[k] / hand.max_grasp / 2, 0.3, 1)),
                    )
                )
                long_side = max(ext)
                if long_side >= 3 * ext[k]:
                    out.append(
                        AffordanceOut("hold", i, _pose(toward, R[:, k], p.center)[None], 0.6)
                    )
            wide = [k for k in horizontal if hand.max_grasp < ext[k] <= hand.shoulder_width]
            if wide and not narrow:
                k = max(wide, key=lambda k: abs(R[:, k] @ side))
                a = R[:, k] * np.sign(R[:, k] @ side)
                left = p.center + a * ext[k] / 2
                right = p.center - a * ext[k] / 2
                poses = np.stack([_pose(-a, UP, left), _pose(a, UP, right)])
                out.append(AffordanceOut("lift", i, poses, 0.7, bimanual=True))
        elif p.kind == "plane":
            area = p.box.extent[0] * p.box.extent[1]
            level = abs(p.normal @ UP)
            if level > 0.95 and area >= hand.min_support_area:
                palm = p.box.center + 0.01 * UP
                out.append(
                    AffordanceOut(
                        "support",
                        i,
                        _pose(-UP, side, palm)[None],
                        float(np.clip(area / 0.25, 0.3, 1)),
                    )
                )
            elif level < 0.2 and area >= hand.min_support_area:
                facing = p.normal if p.normal @ (viewer - p.box.center) > 0 else -p.normal
                palm = p.box.center + 0.01 * facing
                out.append(
                    AffordanceOut(
                        "lean",
                        i,
                        _pose(-facing, UP, palm)[None],
                        float(np.clip(area / 0.5, 0.3, 1)),
                    )
                )
        if p.kind == "box" and top_area(p, RelationConfig()) >= hand.min_support_area:
            top = p.box.center + UP * (np.abs(p.rotation[2]) @ p.extent / 2 + 0.01)
            out.append(AffordanceOut("support", i, _pose(-UP, side, top)[None], 0.8))
        if i in resting and p.kind in ("box", "cylinder", "sphere"):
            back = p.box.center - toward * (
                np.abs(p.box.rotation.T @ toward) @ p.box.extent / 2 + 0.02
            )
            out.append(AffordanceOut("push", i, _pose(toward, side, back)[None], 0.6))
    return out
