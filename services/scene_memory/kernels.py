"""The scene memory's compiled kernels, loaded (or compiled on a machine's first run) before
the first frame rather than with it: the node runs ``warm_up`` at its start and ``avs warm-up``
(the image's build) runs the same, so a container finds every kernel in its cache."""

from __future__ import annotations

from services.scene_memory import cloud_merge, fusion, occupancy, registration


def warm_up(registration_on: bool = True) -> None:
    occupancy.warm_up()
    fusion.warm_up()
    cloud_merge.warm_up()
    if registration_on:
        registration.warm_up()
