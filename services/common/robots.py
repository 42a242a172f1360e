"""Where the robots' MJCF descriptions live. They belong to the simulation, but the kinematics
of the planner and the gaze are computed on the same files (pinocchio), so their location is
shared here, as data: no service imports another."""

from __future__ import annotations

from pathlib import Path

ROBOTS_DIR = Path(__file__).resolve().parents[1] / "sim" / "robots"


def robot_mjcf(robot: str) -> Path:
    path = ROBOTS_DIR / f"{robot}.xml"
    if not path.is_file():
        known = sorted(p.stem for p in ROBOTS_DIR.glob("*.xml"))
        raise FileNotFoundError(f"no robot model {robot!r} in {ROBOTS_DIR} (known: {known})")
    return path
