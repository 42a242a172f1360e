"""The next-best-view node: ``nbv/plan`` queries in (PlanRequest), one planning step each
against the scene memory's scene and occupancy map; the evaluated candidates out on
``nbv/candidates``, the chosen view on ``nbv/next_view`` and as the reply, and (with
``execute``) the platform goal on ``cmd/base`` and the head joints on ``cmd/head``."""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace

import numpy as np

from schemas import (
    BaseGoal,
    BasePose,
    BoxQuery,
    GainRequest,
    Gains,
    HeadCommand,
    NextBestView,
    OccupancySlice,
    PlanRequest,
    PoseCorrection,
    SceneModel,
    ViewCandidates,
)
from services.common.membership import Members
from services.common.node import Node
from services.common.poses import corrected_base
from services.common.robots import robot_mjcf
from services.nbv.config import NbvSettings
from services.nbv.path_cost import path_cost
from services.nbv.planner import Planner, PlannerConfig

log = logging.getLogger("avs.nbv")


def build_planner(settings: NbvSettings) -> Planner:
    """The planning core as ``settings`` configure it (the node's, and ``avs warm-up``'s)."""
    return Planner(
        PlannerConfig(
            radius=settings.radius,
            sampling=settings.sampling,
            strategy=settings.strategy,
            lam=settings.lam,
            lambda_s=settings.lambda_s,
            lambda_quality=settings.lambda_quality,
            max_views=settings.max_views,
            k=settings.k,
            samples=settings.samples,
            every=settings.every,
            best_k=settings.best_k,
            ig_measure=settings.ig_measure,
            max_range=settings.max_range,
            seed=settings.seed,
            roi=(np.array(settings.roi_min), np.array(settings.roi_max))
            if settings.roi_min and settings.roi_max
            else None,
            workspace=(np.array(settings.workspace_min), np.array(settings.workspace_max))
            if settings.workspace_min and settings.workspace_max
            else None,
        ),
        robot_mjcf(settings.robot),
        settings.camera,
        settings.robot,
    )


class NbvNode:
    def __init__(self, node: Node, settings: NbvSettings) -> None:
        self.node, self.s = node, settings
        self.planner = build_planner(settings)
        self.planner.warm_up()  # the kernels now, not in the first step of an episode
        self.lock = threading.Lock()
        self.request_centres: np.ndarray | None = None  # the plan request's, over the settings
        self.base: BasePose | None = None
        self.T_world_odom: np.ndarray | None = None  # memory/pose_correction
        k = node.keys
        # the odometry (200 Hz) is read when a plan starts: only then is the newest decoded
        self.base_states = node.inbox(k.base_state(), BasePose)
        node.subscribe(k.pose_correction(), PoseCorrection, self.on_correction)
        self.out_candidates = node.publisher(k.candidates())
        self.out_next = node.publisher(k.next_view())
        self.out_base = node.publisher(k.cmd_base())
        self.out_head = node.publisher(k.cmd_head())
        # workers: the rendezvous owner of the plan queries answers them and fans the
        # candidates' coarse gains out to every live nbv instance (nbv/gain/<instance>)
        self.members = Members(node.session, k.alive("nbv"), node.instance)
        self.planner.coarse_gains = self.fan_out
        self.workers = 1
        node.serve(k.plan(), self.on_plan, PlanRequest)
        node.serve(k.gain(node.instance), self.on_gain, GainRequest)

    def close(self) -> None:
        self.members.close()

    def on_gain(self, request: GainRequest | None) -> Gains:
        """Coarse gains of a share of another instance's candidates, on this one's map."""
        views = request.views if request is not None else np.zeros((0, 4, 4))
        piece = self._map()
        gains = self.planner.coarse(piece.states, piece.origin, piece.voxel_size, views)
        return Gains(gains=gains, worker=self.node.instance)

    def fan_out(self, poses: np.ndarray) -> np.ndarray:
        """The coarse gains of every candidate, in shares over the live nbv instances (this
        one included); a share whose worker does not answer is computed here."""
        workers = self.members.current()
        shares = np.array_split(np.arange(len(poses)), len(workers))
        gains = np.zeros(len(poses))
        answers: dict[int, np.ndarray] = {}

        def ask(i: int, worker: str) -> None:
            try:
                request = GainRequest(views=poses[shares[i]])
                replies = self.node.query(self.node.keys.gain(worker), request, Gains, 30)
            except Exception as e:  # the share is computed here instead
                log.warning("worker %s did not answer: %r", worker, e)
                return
            if replies and len(replies[0].gains) == len(shares[i]):
                answers[i] = replies[0].gains

        threads = [threading.Thread(target=ask, args=(i, w)) for i, w in enumerate(workers)
                   if w != self.node.instance and len(shares[i])]  # fmt: skip
        for t in threads:
            t.start()
        mine, piece = workers.index(self.node.instance), self._piece

        def here(i: int) -> np.ndarray:
            return self.planner.coarse(
                piece.states, piece.origin, piece.voxel_size, poses[shares[i]]
            )

        answers[mine] = here(mine)  # meanwhile
        for t in threads:
            t.join()
        self.workers = len(answers)  # this one and those that answered
        for i in range(len(workers)):
            if i not in answers:
                answers[i] = here(i)
        for i, idx in enumerate(shares):
            gains[idx] = answers[i]
        return gains

    def on_correction(self, msg: PoseCorrection) -> None:
        self.T_world_odom = np.asarray(msg.T_world_odom, float)

    def _current(self) -> tuple[float, float, float]:
        deadline = time.monotonic() + 10
        while True:
            self.base = self.base_states.newest() or self.base
            if self.base is not None or time.monotonic() > deadline:
                break
            time.sleep(0.01)
        if self.base is None:
            raise RuntimeError("no state/base received: is the sim running?")
        b = self.base  # where the registered map has the platform (thesis A.5)
        return corrected_base(self.T_world_odom, (b.x, b.y, b.yaw), (0.0, 0.0, 0.0))[0]

    def _map(self) -> OccupancySlice:
        """The occupancy map from the scene memory; asked again for a while if none answers
        (a standby taking over from one that died)."""
        lo = np.array(self.s.map_min) if self.s.map_min else np.full(3, -1e3)
        hi = np.array(self.s.map_max) if self.s.map_max else np.full(3, 1e3)
        request = BoxQuery(box_min=lo, box_max=hi)
        deadline = time.monotonic() + 30
        while True:
            pieces = self.node.query(
                self.node.keys.occupancy("slice"), request, OccupancySlice, 30, every_reply=True
            )
            if pieces or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        if not pieces:
            raise RuntimeError("no scene memory answers memory/occupancy/slice")
        return OccupancySlice.join(pieces)

    def centres(self, piece: OccupancySlice | None) -> np.ndarray:
        """The view spheres' centres (m, 3): the settings' (a scene's points of interest), or
        the map's middle at 0.9 m."""
        if self.request_centres is not None:
            return self.request_centres
        if self.s.centre:
            return np.array(self.s.centre, float).reshape(-1, 3)
        if piece is None:
            piece = self._map()
        mid = piece.origin + np.array(piece.states.shape) * piece.voxel_size / 2
        return np.array([[mid[0], mid[1], 0.9]])

    def first_target(self) -> np.ndarray:
        """What the first view looks at: the settings' (a scene's centre, where its view
        spheres are around points of interest), else the first view-sphere centre."""
        if self.s.first_target:
            return np.array(self.s.first_target, float)
        if self.request_centres is not None:
            return self.request_centres[0]
        return self.centres(None)[0]

    def _head(self, joints: dict[str, float], step: int) -> None:
        names = list(joints)
        self.out_head.put(
            HeadCommand(
                seq=step,
                stamp=time.time(),
                names=names,
                mode="position",
                values=np.array([joints[n] for n in names]),
                source="nbv",
            )
        )

    def on_plan(self, request: PlanRequest | None) -> list[NextBestView]:
        """One instance answers (the rendezvous owner of the plan among the live ones)."""
        if not self.members.owns("plan"):
            return []
        request = request or PlanRequest()
        with self.lock:
            return [self._plan(request)]

    def _reply(self, step: int, view: np.ndarray, base, joints: dict[str, float], target,
               **scores) -> NextBestView:  # fmt: skip
        """The NextBestView of a step, published on nbv/next_view (and the query's reply)."""
        reply = NextBestView(
            seq=step, stamp=time.time(), step=step, strategy=self.s.strategy, view=view,
            x=float(base[0]), y=float(base[1]), yaw=float(base[2]), joint_names=list(joints),
            joint_positions=np.array(list(joints.values()), float), target=target, **scores,
        )  # fmt: skip
        self.out_next.put(reply)
        return reply

    def _scene(self, request: PlanRequest) -> None:
        """The episode's facts a request carries (roi, view-sphere centres) over the settings;
        an initial request begins an episode (λ_quality's reference taken anew)."""
        self.request_centres = request.centres if len(request.centres) else None
        if request.roi_min is not None:
            roi = (np.asarray(request.roi_min, float), np.asarray(request.roi_max, float))
            self.planner.config = replace(self.planner.config, roi=roi)
        if request.initial:
            self.planner.first_gain = None

    def _plan(self, request: PlanRequest) -> NextBestView:
        current = self._current()
        step = request.step
        self._scene(request)
        if request.initial:
            centre = self.first_target()
            base, sol = self.planner.first_view(current, centre)
            c = self.planner.config
            cost = path_cost(np.array([current, base]), c.vel_lin, c.vel_rot)
            if request.execute:
                if cost > 0:  # turned in place toward the scene
                    self.out_base.put(
                        BaseGoal(seq=step, stamp=time.time(), goal_id=f"view-{step}",
                                 x=base[0], y=base[1], yaw=base[2])
                    )  # fmt: skip
                self._head(sol.joints, step)
            scores = dict(information_gain=0.0, cost=cost, utility=0.0)
            return self._reply(step, sol.T_world_camera, base, sol.joints, centre, **scores)
        piece = self._piece = self._map()
        scene = None
        if self.s.sampling == "topdown":  # the only sampling that reads the scene graph
            (scene,) = self.node.query(self.node.keys.scene(), None, SceneModel, 30) or [None]
        centres = self.centres(piece)
        result = self.planner.plan(
            centres, scene, piece.states, piece.origin, piece.voxel_size, current,
            request.visited, step, request.excluded, request.blocked,
        )  # fmt: skip
        c = result.candidates
        self.out_candidates.put(
            ViewCandidates(
                seq=step, stamp=time.time(), step=step, strategy=self.s.strategy,
                sampling=self.s.sampling, center=centres[0], views=c.poses.reshape(-1, 4, 4),
                base_pose=c.base.reshape(-1, 3), information_gain=result.gain.astype(float),
                cost=result.cost, saliency=c.saliency, reachable=np.isfinite(result.cost),
                utility=np.where(np.isfinite(result.utility), result.utility, -1.0),
            )
        )  # fmt: skip
        for key, value in result.timings_ms.items():
            self.node.metrics.gauge(key, value)
        b = result.best
        if b is None:
            log.warning("no candidate view: %s", result.detail)
            return self._reply(
                step, np.eye(4), current, {}, centres[0], information_gain=0.0, cost=0.0,
                utility=0.0, terminate=True, reason="no_candidates", detail=result.detail,
            )  # fmt: skip
        if result.looked_around:
            log.info(
                "no view sphere's view has a path from (%.2f, %.2f): looking around from here",
                *current[:2],
            )
        joints = c.joints[b]
        reply = self._reply(
            step, c.poses[b], c.base[b], joints, c.targets[b],
            information_gain=float(result.gain[b]), cost=float(result.cost[b]),
            utility=float(result.utility[b]), terminate=result.terminate, reason=result.reason,
            workers=self.workers,
        )  # fmt: skip
        if request.execute and not result.terminate:
            path = result.path
            self.out_base.put(
                BaseGoal(
                    seq=step, stamp=time.time(), goal_id=f"view-{step}",
                    x=reply.x, y=reply.y, yaw=reply.yaw,
                    path=path[1:-1] if path is not None and len(path) > 2 else None,
                )
            )  # fmt: skip
            self._head(joints, step)
        log.info(
            "planned",
            extra={
                "step": step, "candidates": len(result.gain),
                "reachable": int(np.isfinite(result.cost).sum()), "ig": reply.information_gain,
                "cost": reply.cost, "terminate": reply.terminate, **result.timings_ms,
            },
        )  # fmt: skip
        return reply
