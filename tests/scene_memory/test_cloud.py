"""The registered cloud grows frame by frame with one point per 1 cm voxel, a voxel's first
point staying and the oldest dropped beyond the cap: the incremental merge (``_add_to_cloud``)
gives exactly what re-deduplicating the whole cloud every frame gave."""

from __future__ import annotations

import numpy as np
import pytest

from services.scene_memory import memory as memory_module
from services.scene_memory.fusion import voxel_keys
from services.scene_memory.memory import SceneMemory
from services.scene_memory.state import dump, load


def _reference(frames, cap: int):
    cloud, colours, seen = (
        np.zeros((0, 3), np.float32),
        np.zeros((0, 3), np.uint8),
        np.zeros((0, 3), np.float32),
    )
    for pts, rgb, eye in frames:
        merged = np.concatenate([cloud, pts])
        col = np.concatenate([colours, rgb])
        vp = np.concatenate([seen, np.broadcast_to(eye.astype(np.float32), pts.shape)])
        _, first = np.unique(voxel_keys(merged, 0.01), return_index=True)
        first = np.sort(first)[-cap:]
        cloud, colours, seen = merged[first], col[first], vp[first]
    return cloud, colours, seen


@pytest.mark.parametrize("cap", [6000, 1000])  # 1000: a frame alone is past the cap
def test_incremental_cloud_equals_whole_cloud_dedup(monkeypatch, cap):
    monkeypatch.setattr(memory_module, "MAX_CLOUD", cap)
    rng = np.random.default_rng(7)
    frames = []
    for i in range(12):  # overlapping 0.3 m boxes drifting along x, 1500 points each
        pts = (rng.uniform(0, 0.3, (1500, 3)) + np.array([0.05 * i, 0, 0])).astype(np.float32)
        frames.append((pts, rng.integers(0, 255, (1500, 3), dtype=np.uint8), rng.normal(size=3)))
    m = SceneMemory()
    for k, (pts, rgb, eye) in enumerate(frames):
        m._add_to_cloud(pts, rgb, eye)
        if k == 5:  # a snapshot between frames: the voxel keys are rebuilt after it
            m = load(dump(m, 6))[0]
            assert m._cloud_keys is None
        cloud, colours, seen = _reference(frames[: k + 1], cap)
        assert np.array_equal(m.cloud, cloud) and np.array_equal(m.colours, colours), k
        assert np.array_equal(m.viewpoints, seen), k
    assert len(m.cloud) == cap  # the cap was reached and the oldest points went
    assert np.array_equal(np.sort(voxel_keys(m.cloud, 0.01)), m._cloud_index)
