"""The gaze in the registered world (issue 15, thesis A.5): the odometry drifts, view
registration publishes T_world_odom on memory/pose_correction, and the gaze places the platform
where the registered map has it, so a world target is fixated where it really is."""

from __future__ import annotations

import math

import numpy as np
import pytest

from schemas import (
    BasePose,
    GazeTarget,
    HeadCommand,
    ImuSample,
    JointState,
    PoseCorrection,
    decode,
)
from services.common import Node
from services.common.poses import corrected_base
from services.gaze.config import GazeSettings
from services.gaze.node import GazeNode
from services.sim.sensors import planar

TARGET = np.array([1.6, 0.2, 0.8])


def test_a_correction_moves_the_platform_pose_and_turns_its_velocity():
    T = planar(0.1, -0.2, math.radians(10))
    (x, y, yaw), (vx, vy, w) = corrected_base(T, (1.0, 0.0, 0.0), (0.0, 0.2, 0.3))
    c, s = math.cos(math.radians(10)), math.sin(math.radians(10))
    assert (x, y, yaw) == pytest.approx((0.1 + c, -0.2 + s, math.radians(10)))
    assert (vx, vy, w) == pytest.approx((-0.2 * s, 0.2 * c, 0.3))
    assert corrected_base(None, (1.0, 2.0, 3.0), (4.0, 5.0, 6.0)) == ((1, 2, 3), (4, 5, 6))


@pytest.fixture
def gaze():
    settings = GazeSettings(mode="peer", multicast=False, listen=[], egosphere_rate=0, okr_gain=0)
    with Node("gaze", settings) as node:
        yield GazeNode(node, settings)


def fixation_error_deg(gaze: GazeNode, true_base: tuple[float, float, float]) -> float:
    """The gaze's angle error at the true platform pose, with the joints it commanded."""
    kin = gaze.stab.kin
    joints = dict(zip(kin.joint_names, [float(kin.q[kin.idx_q[n]]) for n in kin.joint_names],
                      strict=True))  # fmt: skip
    kin.update(kin.configuration(true_base, joints))
    return math.degrees(kin.fixation("head_rgbd", TARGET)[2])


def run(gaze: GazeNode, believed: tuple[float, float, float], steps: int = 400) -> None:
    """``steps`` control steps at 1 kHz with the platform still at ``believed`` (odometry),
    the head joints integrating the head commands the node publishes (a perfect servo)."""
    names = gaze.kin.joint_names
    q = np.array([float(gaze.stab.kin.q[gaze.kin.idx_q[n]]) for n in names])
    sent: list[HeadCommand] = []
    # what the node would publish on cmd/head
    gaze.out_head.put_raw = lambda payload: sent.append(decode(payload, HeadCommand))
    gaze.on_target(GazeTarget(seq=1, stamp=0.0, point=TARGET, source="manual", hold_s=1e9))
    for k in range(steps):
        t = k * 1e-3
        gaze.on_joints(JointState(seq=k, stamp=t, names=names, position=q,
                                  velocity=np.zeros(len(q))))  # fmt: skip
        gaze.on_base(BasePose(seq=k, stamp=t, x=believed[0], y=believed[1], yaw=believed[2]))
        gaze.on_imu(ImuSample(seq=k, stamp=t, angular_velocity=np.zeros(3),
                              linear_acceleration=np.zeros(3),
                              orientation=np.array([1.0, 0, 0, 0])))  # fmt: skip
        if sent:  # (the very first step may be late, while the compiled kernel loads)
            v = dict(zip(sent[-1].names, sent[-1].values.tolist(), strict=True))
            q = q + 1e-3 * np.array([v.get(n, 0.0) for n in names])
            sent.clear()
    kin = gaze.stab.kin  # the head as commanded, at the platform pose the gaze used
    kin.update(kin.configuration(gaze._base(gaze.base)[0], dict(zip(names, q, strict=True))))


def test_the_gaze_fixates_the_world_target_once_the_drift_is_corrected(gaze):
    """The robot is at the origin; its odometry believes it 12 cm forward and 4° turned. The
    uncorrected gaze fixates the target as seen from the wrong place (about 4-8° off); with the
    registration's correction it is on the target within a tenth of a degree."""
    true_base, believed = (0.0, 0.0, 0.0), (0.12, 0.0, math.radians(4))
    run(gaze, believed)
    off = fixation_error_deg(gaze, true_base)
    T_world_odom = planar(*true_base) @ np.linalg.inv(planar(*believed))
    gaze.on_correction(PoseCorrection(T_world_odom=T_world_odom, camera="head_rgbd",
                                      frame_seq=0, accepted=True))  # fmt: skip
    run(gaze, believed)
    on = fixation_error_deg(gaze, true_base)
    assert off > 3.0 and on < 0.1, (off, on)
