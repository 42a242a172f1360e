"""Where the robot's world is: the box the occupancy map covers, derived from the scene.

The map must hold everything the planner reasons about: the roi, the platform at its start,
every platform pose a view of the view sphere may need (Eq. 4.2: within the sphere's radius of
its centre, horizontally), and the scene's ``workspace`` site where there is one. Outside the
map is unknown space, never an obstacle; but a start the map does not cover has no clearance
to plan from, which is why the map is made to cover it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: below the floor and up to at least this height (m): the robot's head camera is under 1.9 m
FLOOR_Z, CEILING_Z = -0.05, 2.2


def map_bounds(
    roi: tuple[np.ndarray, np.ndarray],
    start_xy: Sequence[float],
    centres: np.ndarray,
    *,
    radius: float = 1.5,
    footprint: float = 0.45,
    margin: float = 0.3,
    workspace: tuple[np.ndarray, np.ndarray] | None = None,
    platform_xy: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(min corner, max corner) of the map: the roi grown by ``margin``; the footprint (plus
    ``margin``) at ``start_xy`` and at every platform position in ``platform_xy`` (n, 2); the
    discs of ``radius`` around each view-sphere centre (m, 3) grown by the footprint, clipped
    to the ``workspace`` (where the platform may go) which is covered too."""
    lo = np.asarray(roi[0], float) - margin
    hi = np.asarray(roi[1], float) + margin
    reach = footprint + margin
    places = [np.asarray(start_xy, float)[:2]]
    if platform_xy is not None:
        places += list(np.asarray(platform_xy, float).reshape(-1, 2))
    for p in places:
        lo[:2], hi[:2] = np.minimum(lo[:2], p - reach), np.maximum(hi[:2], p + reach)
    for c in np.asarray(centres, float).reshape(-1, 3):
        s_lo, s_hi = c[:2] - radius - reach, c[:2] + radius + reach
        if workspace is not None:
            s_lo = np.maximum(s_lo, np.asarray(workspace[0], float)[:2] - reach)
            s_hi = np.minimum(s_hi, np.asarray(workspace[1], float)[:2] + reach)
        lo[:2], hi[:2] = np.minimum(lo[:2], s_lo), np.maximum(hi[:2], s_hi)
    if workspace is not None:
        lo[:2] = np.minimum(lo[:2], np.asarray(workspace[0], float)[:2])
        hi[:2] = np.maximum(hi[:2], np.asarray(workspace[1], float)[:2])
    lo[2], hi[2] = FLOOR_Z, max(CEILING_Z, hi[2])
    return lo, hi
