"""Where the robots' MJCF descriptions live. They belong to the simulation, but the kinematics
of the planner and the gaze are computed on the same files (pinocchio), so their location is
shared here, as data: no service imports another."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

ROBOTS_DIR = Path(__file__).resolve().parents[1] / "sim" / "robots"


#: the joints' speed limits (rad/s or m/s) the sim's servos keep to and the controllers plan
#: with (a joint not named: 1 rad/s in the sim; the gaze stabiliser's default is 2)
JOINT_SPEED: dict[str, dict[str, float]] = {
    "armar6": {"torso_lift": 0.1, "neck_yaw": 2.0, "neck_pitch": 2.0},
    "armar3": {
        "hip_yaw": 1.0,
        "neck_lower_pitch": 2.0,
        "neck_roll": 2.0,
        "neck_yaw": 2.0,
        "neck_upper_pitch": 2.0,
        "eye_tilt": 5.0,
        "eye_pan_left": 5.0,
        "eye_pan_right": 5.0,
        **{f"{s}_finger_{f}": 0.15 for s in "lr" for f in "ab"},
    },
}


def robot_mjcf(robot: str) -> Path:
    path = ROBOTS_DIR / f"{robot}.xml"
    if not path.is_file():
        known = sorted(p.stem for p in ROBOTS_DIR.glob("*.xml"))
        raise FileNotFoundError(f"no robot model {robot!r} in {ROBOTS_DIR} (known: {known})")
    return path


def _frame(element: ET.Element) -> np.ndarray:
    """T_body_element of an MJCF camera or site: ``pos`` and ``xyaxes`` (MuJoCo's axes)."""
    pos = np.array([float(v) for v in element.get("pos", "0 0 0").split()])
    xy = np.array([float(v) for v in element.get("xyaxes", "1 0 0 0 1 0").split()])
    x, y = xy[:3] / np.linalg.norm(xy[:3]), xy[3:] / np.linalg.norm(xy[3:])
    y = y - (y @ x) * x
    y /= np.linalg.norm(y)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, np.cross(x, y)])
    T[:3, 3] = pos
    return T


def site_mount(mjcf: Path, site: str) -> tuple[str, np.ndarray]:
    """(parent body, T_body_site) of a site in an MJCF file (e.g. a hand's grasp frame)."""
    for body in ET.parse(mjcf).getroot().iter("body"):
        for s in body.findall("site"):
            if s.get("name") == site:
                return body.get("name"), _frame(s)
    raise KeyError(f"{mjcf} has no site {site!r}")


def geom_position(mjcf: Path, geom: str) -> tuple[str, np.ndarray]:
    """(parent body, position in it) of a named geom in an MJCF file (e.g. a hand's marker)."""
    for body in ET.parse(mjcf).getroot().iter("body"):
        for g in body.findall("geom"):
            if g.get("name") == geom:
                return body.get("name"), np.array([float(v) for v in g.get("pos", "0 0 0").split()])
    raise KeyError(f"{mjcf} has no geom {geom!r}")


def camera_mount(mjcf: Path, camera: str) -> tuple[str, np.ndarray]:
    """(parent body, T_body_optical) of a camera in an MJCF file: MuJoCo cameras look along
    their −z with y up; the optical frame looks along +z with y down."""
    for body in ET.parse(mjcf).getroot().iter("body"):
        for cam in body.findall("camera"):
            if cam.get("name") != camera:
                continue
            T = _frame(cam)
            T[:3, 1:3] = -T[:3, 1:3]  # MuJoCo camera (−z forward, y up) → optical frame
            return body.get("name"), T
    raise KeyError(f"{mjcf} has no camera {camera!r}")
