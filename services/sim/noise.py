"""Depth noise of a structured-light sensor (Primesense Carmine / Kinect v1), SPEC §2.

- axial noise σ(z) = 0.0012 + 0.0019·(z − 0.4)² m (Nguyen et al. 2012, as in the SPEC);
- quantisation: the sensor measures disparity in 1/8 pixel steps, so depth comes in steps of
  about z²/(8·f·b) (f focal length in pixels, b = 7.5 cm baseline);
- missing pixels on depth edges, where neighbours differ by more than ``edge_jump`` of the depth.
"""

from __future__ import annotations

import numpy as np

BASELINE = 0.075
SUBPIXEL = 8.0


def sigma(z: np.ndarray) -> np.ndarray:
    """Axial standard deviation of a depth reading at z metres."""
    return 0.0012 + 0.0019 * (z - 0.4) ** 2


def structured_light(
    depth: np.ndarray,
    rng: np.random.Generator,
    focal_px: float,
    *,
    edge_jump: float = 0.05,
    edge_dropout: float = 0.7,
) -> np.ndarray:
    """Noisy copy of ``depth`` (metres, float32, 0 = no return; zeros stay zeros)."""
    z = np.array(depth, dtype=np.float32)
    valid = z > 0
    zv = z[valid]
    zv += rng.standard_normal(zv.size, dtype=np.float32) * sigma(zv)
    fb = np.float32(focal_px * BASELINE * SUBPIXEL)  # disparity in 1/8 px = fb / z
    disparity = np.maximum(np.rint(fb / np.maximum(zv, np.float32(1e-3))), np.float32(1.0))
    z[valid] = fb / disparity
    # missing returns on depth discontinuities, on both sides of the jump
    jump = np.zeros(z.shape, bool)
    h = np.abs(depth[:, 1:] - depth[:, :-1]) > edge_jump * np.maximum(depth[:, 1:], depth[:, :-1])
    jump[:, 1:] |= h
    jump[:, :-1] |= h
    v = np.abs(depth[1:] - depth[:-1]) > edge_jump * np.maximum(depth[1:], depth[:-1])
    jump[1:] |= v
    jump[:-1] |= v
    edges = np.flatnonzero(jump)
    z.reshape(-1)[edges[rng.random(edges.size) < edge_dropout]] = 0.0
    return z
