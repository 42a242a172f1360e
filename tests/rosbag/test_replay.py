"""``avs replay-bag`` end to end: bags in the TUM RGB-D layout written from sim frames,
replayed by the command into a perception process over Zenoh, give the observations the
same frames give when published directly, with primitives where the scene's objects are
(world frame from the bag's /tf)."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import pytest
import zenoh
from pydantic import BaseModel

from avs.cli import build_parser
from avs.commands.replay_bag import config_from
from schemas import Keys, RgbdFrame, SceneObservation, decode, encode
from tests.conftest import (
    ROOT,
    Processes,
    avs_env,
    free_port,
    matched_publisher,
    session_config,
    wait_for,
)
from tests.rosbag.bags import DEPTH, EPOCH, INFO, RGB, as_stored, tabletop_views, write_tum_bag

KEYS = Keys()
#: what may differ between a direct and a replayed frame's observation: the worker's counter,
#: and the stamps (the bag's are EPOCH later)
VOLATILE = {"seq", "stamp", "frame_stamp", "timings_ms"}


@dataclass
class Stack:
    endpoint: str
    client: zenoh.Session
    frames: list[RgbdFrame]
    truth: dict[str, np.ndarray]
    direct: list[SceneObservation] = field(default_factory=list)
    seen: list[SceneObservation] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)


@pytest.fixture(scope="module")
def stack() -> Iterator[Stack]:
    """A router, a perception process, and the observations of the frames (depth in whole
    millimetres, as both encodings carry it) published directly, one at a time."""
    frames, truth = tabletop_views(320, 240)
    frames = [as_stored(f, "16UC1") for f in frames]
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(session_config("router", listen=[endpoint]))
    client = zenoh.open(session_config("client", connect=[endpoint]))
    procs = Processes()
    s = Stack(endpoint, client, frames, truth)

    def keep(sample: zenoh.Sample) -> None:
        with s.lock:
            s.seen.append(decode(sample.payload.to_bytes(), SceneObservation))

    subscriber = client.declare_subscriber(KEYS.observation(), keep)
    try:
        procs.python(["-m", "services.perception", "--instance", "p0"], env=avs_env(endpoint))
        out = matched_publisher(client, KEYS.rgbd("head_rgbd"), timeout=60)
        for i, f in enumerate(frames):
            out.put(encode(f.model_copy(update={"stamp": EPOCH + f.stamp})))
            wait_for(lambda i=i: len(s.seen) == i + 1, 30, f"the observation of frame {i}")
        s.direct = list(s.seen)
        out.undeclare()
        yield s
    finally:
        procs.stop_all()
        subscriber.undeclare()
        client.close()
        router.close()


def _same(a, b, path: str = "") -> None:
    """Equal values, arrays and floats to 1e-6 (the pose went through quaternions)."""
    if isinstance(a, BaseModel):
        assert type(a) is type(b), path
        for name in type(a).model_fields:
            if not (path == "" and name in VOLATILE):
                _same(getattr(a, name), getattr(b, name), f"{path}.{name}")
    elif isinstance(a, np.ndarray):
        assert a.shape == b.shape, path
        np.testing.assert_allclose(a, b, atol=1e-6, err_msg=path)
    elif isinstance(a, float):
        assert abs(a - b) <= 1e-6, (path, a, b)
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), (path, len(a), len(b))
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same(x, y, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for k in a:
            _same(a[k], b[k], f"{path}[{k}]")
    else:
        assert a == b, (path, a, b)


def _centre(p) -> np.ndarray:
    return np.asarray(p.model.center if p.kind != "plane" else p.obb.center)


@pytest.mark.parametrize(
    ("ros", "depth", "rgb", "compressed"),
    [(1, "32FC1", "rgb8", None), (2, "16UC1", "bgr8", None),
     (1, "16UC1", "rgb8", "png"), (2, "16UC1", "bgr8", "png")],
)  # fmt: skip
def test_replayed_bag_gives_the_direct_observations_where_the_scene_is(
    tmp_path, stack, ros, depth, rgb, compressed
):
    """Raw images, and compressed ones (PNG colour, compressedDepth 16UC1: both lossless, so
    the observations are the same to the bit)."""
    bag = tmp_path / ("tum.bag" if ros == 1 else "tum")
    write_tum_bag(bag, stack.frames, ros, depth, rgb_encoding=rgb, compressed=compressed)
    with stack.lock:
        before = len(stack.seen)
    t0 = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "avs.cli", "replay-bag", str(bag), "--rgb", RGB, "--depth", DEPTH,
         "--camera-info", INFO, "--tf", "--rate", "2", "--connect", stack.endpoint],
        cwd=ROOT, env=avs_env(stack.endpoint), capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert f"replay-bag: 3 frames of {bag} on avs/armar6/sensors/rgbd/head_rgbd" in done.stderr
    wait_for(lambda: len(stack.seen) >= before + 3, 30, "3 observations of the replay")
    replayed = stack.seen[before:]
    assert [o.frame_seq for o in replayed] == [0, 1, 2]
    assert time.monotonic() - t0 < 30
    for got, want in zip(replayed, stack.direct, strict=True):
        assert got.frame_stamp == pytest.approx(want.frame_stamp, abs=1e-6)
        assert len(got.primitives) >= 5
        _same(got, want)

    # where the scene is: the table top's plane and the objects' centres, in the sim's world
    table = stack.truth["table_top"]
    tops = [p for o in replayed for p in o.primitives
            if p.kind == "plane" and abs(p.model.normal[2]) > 0.98 and p.obb.extent.max() > 0.5
            and abs(p.obb.center[2] - table[2]) < 0.1]  # fmt: skip
    assert tops and all(abs(p.obb.center[2] - table[2]) < 0.01 for p in tops)
    for name in ("can", "ball", "bottle"):
        errors = [np.linalg.norm(_centre(p) - stack.truth[name]) for o in replayed
                  for p in o.primitives if p.kind != "plane"]  # fmt: skip
        assert min(errors) < 0.03, (name, min(errors))


def test_the_command_refuses_a_bad_bag_in_one_line(tmp_path):
    (tmp_path / "notes.txt").write_text("not a bag")
    (tmp_path / "broken.bag").write_bytes(b"#ROSBAG V2.0\n" + bytes(100))
    parser = build_parser()
    topics = ["--rgb", RGB, "--depth", DEPTH, "--camera-info", INFO]
    for argv, message in [
        ([str(tmp_path / "x.bag"), *topics], f"bag {tmp_path / 'x.bag'}: no such file"),
        ([str(tmp_path), *topics, "--world-frame", "map"], "--world-frame needs --tf"),
        ([str(tmp_path / "notes.txt"), *topics], "neither a ROS 1 .bag file nor a ROS 2 bag"),
        ([str(tmp_path / "broken.bag"), *topics], "broken.bag: cannot be read"),
    ]:
        args = parser.parse_args(["replay-bag", *argv])
        with pytest.raises(SystemExit) as stop:
            args.func(args)
        assert str(stop.value.code).startswith("avs replay-bag: ") and message in str(
            stop.value.code
        )


def test_the_command_turns_its_flags_into_the_replay_config():
    topics = ["--rgb", RGB, "--depth", DEPTH, "--camera-info", INFO]
    args = build_parser().parse_args(["replay-bag", "x.bag", *topics, "--pose", "1", "2", "1.2",
                                      "0", "30", "90", "--limit", "5", "--depth-range", "0.5",
                                      "4", "--camera", "desk"])  # fmt: skip
    config = config_from(args)
    assert (config.rgb, config.depth, config.camera_info) == (RGB, DEPTH, INFO)
    assert (config.tf, config.limit, config.camera, config.max_dt) == (False, 5, "desk", 0.02)
    assert (config.depth_min, config.depth_max, config.depth_scale) == (0.5, 4.0, None)
    # body x forward along world +y, 30° down: the optical axis
    np.testing.assert_allclose(config.T_world_camera[:3, 2], [0, np.cos(np.pi / 6), -0.5],
                               atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(config.T_world_camera[:3, 3], [1, 2, 1.2])
