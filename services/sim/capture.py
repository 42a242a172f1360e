"""What a camera delivers and what the truth is, as wire messages: shared by the sim node and
the command-line tools that render a view without Zenoh (avs perceive, avs fuse …)."""

from __future__ import annotations

import numpy as np

from schemas import GroundTruth, GroundTruthObject, RgbdFrame
from services.sim import ground_truth, noise
from services.sim.render import CameraRenderer, intrinsics
from services.sim.world import World


def snapshot(world: World, renderer: CameraRenderer, camera: str) -> tuple[np.ndarray, float]:
    """Copy the state to render (hold the world's lock around this); returns the camera pose
    and the time."""
    renderer.snapshot(world.data, world.cameras[camera])
    return world.T_world_camera(camera), world.time


def frame(
    world: World,
    renderer: CameraRenderer,
    camera: str,
    T_world_camera: np.ndarray,
    stamp: float,
    seq: int,
    rng: np.random.Generator | None,
    joints: tuple[list[str], np.ndarray] | None = None,
) -> RgbdFrame:
    """Render the last snapshot: RGB, and depth for RGB-D cameras (0 outside the sensor's
    range; structured-light noise drawn from ``rng`` unless it is None). The frame carries the
    joint positions of the snapshot's instant (``joints``; default: the world's now), which
    perception masks the robot's own body with."""
    info = world.robot.camera(camera)
    rgb, depth = renderer.render(depth=info.depth_range is not None)
    K = intrinsics(world.model, world.cameras[camera], renderer.width, renderer.height)
    dmin = dmax = 0.0
    if depth is not None:
        dmin, dmax = info.depth_range
        depth = np.where((depth >= dmin) & (depth <= dmax), depth, 0.0).astype(np.float32)
        if rng is not None:
            depth = noise.structured_light(depth, rng, K.fx)
    names, q = joints if joints is not None else world.joint_state()[:2]
    return RgbdFrame(
        seq=seq,
        stamp=stamp,
        camera=camera,
        intrinsics=K,
        rgb=rgb,
        depth=depth,
        T_world_camera=T_world_camera,
        depth_min=dmin,
        depth_max=dmax,
        joint_names=names,
        joint_positions=q,
    )


def segmentation(
    world: World, renderer: CameraRenderer, camera: str
) -> tuple[list[str], np.ndarray]:
    """Labels and the label index of every pixel (-1: no scene body) at the current state."""
    labels, lookup = ground_truth.segmentation_labels(world)
    ids = renderer.segmentation(world.data, world.cameras[camera])
    return labels, np.where(ids >= 0, lookup[np.maximum(ids, 0)], -1).astype(np.int32)


def unowned_depth_fraction(
    world: World, renderer: CameraRenderer, camera: str, depth: np.ndarray
) -> float:
    """Share of the depth returns (depth > 0) on pixels no geom covers at the current state: a
    sanity figure, 0 when the camera sees physical geometry only."""
    ids = renderer.segmentation(world.data, world.cameras[camera])
    returns = np.asarray(depth) > 0
    return float((returns & (ids < 0)).sum() / max(1, returns.sum()))


def ground_truth_message(
    world: World,
    edges: list[tuple[str, str]],
    closure: list[tuple[str, str]],
    camera: str = "",
    labels: list[str] | None = None,
    seg: np.ndarray | None = None,
    T_world_odom: np.ndarray | None = None,
) -> GroundTruth:
    """The truth now; ``T_world_odom`` is the odometry's error when the sensor models run."""
    roi = world.info.roi
    return GroundTruth(
        stamp=world.time,
        scene=world.info.name,
        robot=world.robot.name,
        objects=[
            GroundTruthObject(name=o.name, kind=o.kind, pose=o.pose, size=o.size, static=o.static)
            for o in ground_truth.objects(world)
        ],
        support_edges=edges,
        support_closure=closure,
        camera=camera if seg is not None else "",
        segmentation=seg,
        labels=labels or [],
        roi_min=roi[0] if roi else None,
        roi_max=roi[1] if roi else None,
        T_world_camera=world.T_world_camera(camera or world.robot.default_cameras[0]),
        T_world_odom=T_world_odom,
    )


def view(
    world: World,
    renderer: CameraRenderer,
    camera: str,
    rng: np.random.Generator | None,
    seq: int = 0,
) -> tuple[RgbdFrame, GroundTruth]:
    """One frame of ``camera`` and the full ground truth of that moment (no Zenoh, no locks:
    for tools that own the world)."""
    T, stamp = snapshot(world, renderer, camera)
    f = frame(world, renderer, camera, T, stamp, seq, rng)
    labels, seg = segmentation(world, renderer, camera)
    edges, closure = ground_truth.support_graph(world.model, world.data, world.info)
    return f, ground_truth_message(world, edges, closure, camera, labels, seg)
