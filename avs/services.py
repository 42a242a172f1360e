"""The services of SPEC §1 and how to start one as a local process."""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ServiceInfo:
    name: str
    summary: str
    scalable: bool = False
    #: one instance works at a time, the others stand by to take over (a writer): each gets
    #: every core, not a share of them
    one_active: bool = False

    @property
    def module(self) -> str:
        return f"services.{self.name}"

    def exists(self) -> bool:
        """Whether the service is implemented: its package has a ``__main__``."""
        spec = importlib.util.find_spec(self.module)
        if spec is None or not spec.submodule_search_locations:
            return False
        return any((Path(p) / "__main__.py").is_file() for p in spec.submodule_search_locations)

    def argv(self) -> list[str]:
        """Arguments after the interpreter: ``python -m services.<name>``. compose.yaml runs the
        same command."""
        return ["-m", self.module]


SERVICES: tuple[ServiceInfo, ...] = (
    ServiceInfo("sim", "MuJoCo ARMAR-6 / ARMAR-III: RGB-D, IMU, joints, odometry, ground truth"),
    ServiceInfo("perception", "RGB-D → primitives, spatial + support graph, affordances", True),
    # more than one scene memory: one writes, the others stand by to take over
    ServiceInfo(
        "scene_memory", "fusion across views, occupancy map, persistence", True, one_active=True
    ),
    ServiceInfo("nbv", "next-best-view: sampling, information gain, path cost, utility", True),
    ServiceInfo("gaze", "ego-sphere view selection and gaze stabilisation"),
    ServiceInfo("explorer", "the active-vision loop: plan, move, settle, capture, decide"),
)

BY_NAME = {s.name: s for s in SERVICES}


def existing() -> list[ServiceInfo]:
    return [s for s in SERVICES if s.exists()]
