"""The scene memory's two sides, each under a lock of its own: a depth frame is integrated
while an observation is being fused and an observation fused while a frame is integrated,
and an observation of the frame being registered waits for that frame's correction only."""

from __future__ import annotations

import threading

import pytest

from schemas import SceneModel, decode
from services.common.node import Node
from services.scene_memory.config import SceneMemorySettings
from services.scene_memory.memory import MemoryConfig, SceneMemory
from services.scene_memory.node import SceneMemoryNode
from services.scene_memory.registration import RegistrationConfig
from tests.conftest import wait_for
from tests.scene_memory.views import BOUNDS_MAX, BOUNDS_MIN, VOXEL


@pytest.fixture
def memory(tmp_path):
    settings = SceneMemorySettings(
        mode="peer", multicast=False, listen=[], data_dir=tmp_path, voxel=VOXEL,
        bounds_min=BOUNDS_MIN, bounds_max=BOUNDS_MAX,
    )  # fmt: skip
    with Node("scene_memory", settings, announce=False) as node:
        m = SceneMemoryNode(node, settings)
        yield m
        m.close()


def done_within(work, seconds: float) -> bool:
    t = threading.Thread(target=work, daemon=True)
    t.start()
    t.join(seconds)
    return not t.is_alive()


def test_neither_side_waits_for_the_other(memory, updates):
    frames = [m for kind, m in updates if kind == "frame"]
    observations = [m for kind, m in updates if kind == "observation"]
    with memory.model_lock:  # an observation being fused all along
        assert done_within(lambda: memory.on_frame(frames[0]), 30)
    assert memory.memory.occupancy.frames == 1
    with memory.map_lock:  # a frame being integrated all along
        assert done_within(lambda: memory.on_observation(observations[0]), 30)
    assert len(memory.memory.fusion.prims) > 0 and memory.n == 2


def test_an_observation_of_the_frame_in_registration_waits_for_its_correction(memory, updates):
    obs = next(m for kind, m in updates if kind == "observation")
    memory.registering = obs.frame_seq  # its frame is being registered
    fused = threading.Event()
    threading.Thread(target=lambda: (memory.on_observation(obs), fused.set()), daemon=True).start()
    assert not fused.wait(0.5)  # it waits ...
    memory._registered()  # ... for the correction, not for the map
    assert fused.wait(10)
    # a newer frame in registration does not hold it up: its correction is not this one's
    memory.registering = obs.frame_seq + 1
    assert done_within(lambda: memory.on_observation(obs), 10)


def test_only_a_frame_that_will_be_registered_holds_up_observations(updates):
    """A frame makes observations of it (or later) wait for its correction only where it is
    registered: registration on, a cloud to align to, its interval since the last one
    passed. Every other frame leaves the correction as it is: nothing to wait for."""
    frames = [m for kind, m in updates if kind == "frame"]
    first, later = frames[0], frames[1]
    box = {"bounds_min": BOUNDS_MIN, "bounds_max": BOUNDS_MAX}
    off = SceneMemory(MemoryConfig(**box))
    on = SceneMemory(
        MemoryConfig(**box, registration=RegistrationConfig(), registration_interval=0.5)
    )
    assert not on.will_register(first)  # nothing to align to yet: the first frame is the map
    on.integrate(first)
    off.integrate(first)
    assert not off.will_register(later)
    assert on.will_register(later)  # the first registration
    on.integrate(later)
    soon = later.model_copy(update={"seq": later.seq + 1, "stamp": later.stamp + 0.2})
    due = later.model_copy(update={"seq": later.seq + 2, "stamp": later.stamp + 0.6})
    assert not on.will_register(soon) and on.will_register(due)


def test_observations_that_waited_are_fused_and_published_as_one_model(memory, updates):
    """Fusion behind: the observations that waited are fused in order and one model holds
    them all, naming every frame (``fused_frames``); alone, one model per observation."""
    observations = [m for kind, m in updates if kind == "observation"][:3]
    models: list[SceneModel] = []
    sub = memory.node.session.declare_subscriber(
        memory.node.keys.scene(), lambda s: models.append(decode(s.payload.to_bytes(), SceneModel))
    )
    try:
        memory.on_observations(observations[:2])
        memory.on_observations(observations[2:])
        wait_for(lambda: len(models) == 2, 10, "two models")
    finally:
        sub.undeclare()
    frames = [o.frame_seq for o in observations]
    assert models[0].fused_frames == frames[:2] and models[0].frame_seq == frames[1]
    assert models[1].fused_frames == frames[2:] and models[1].n_views == 3
    assert memory.n == 3  # each journaled on its own
    assert memory.scene().fused_frames == []  # a query's reply names none
