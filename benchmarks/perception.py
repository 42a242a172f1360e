"""One 640×480 tabletop_clutter frame (start view, depth noise on) through our perception
pipeline three times over: with our RANSAC, with pyRANSAC-3D's and with Open3D's doing
Algorithm 1's fitting step; then Algorithm 1's fitting calls (as it made them with ours)
replayed through each fitter, first on equal work.

Everything but the fitting is the same code on the same input: the same stride-2 cloud (77k
points), the same segments, the same per-fit subsample (≤ τ_max = 4000 points of a segment
part, drawn by the same seeded generator), the same hypothesis budget (48 planes, 24 for the
second plane, 32 cylinders, 32 spheres), the same inlier distance d(z) per segment, then the
same model choice, clustering, boxes and graphs. Each result is scored with the same
InlierIndex (thesis Eq. 3.11) against the ground truth.

Like for like (``like_for_like_vs_pyransac3d``: pyRANSAC-3D's ms ÷ ours, > 1: ours faster):
the replay of ours' fitting calls through ours with ``subset=None`` and through pyRANSAC-3D.
Equal: each call's points (identical arrays), hypothesis budget and inlier distance; every
hypothesis scored on every one of the call's points (pyRANSAC-3D scores all it is given; ours
is made to: as shipped it scores 500 drawn at random, ``ransac.SUBSET``. Scoring ours on all
points rather than pyRANSAC-3D on our 500 keeps the peer's work as it is); one thread each
(ours' fitting kernels are serial; numpy's OpenBLAS held to one thread for both replays:
``_threads.blas_threads``); both warm (a replay first, untimed). What differs, by design of
each: ours tests each point's normal too while scoring (pyRANSAC-3D: the distance only);
cylinders from 2 oriented points (pyRANSAC-3D: 3 points) and spheres from 2 oriented points
(pyRANSAC-3D: 4); ours drops hypotheses outside the radius bounds [r_min, r_max] before
scoring them (pyRANSAC-3D scores all, and its best is dropped afterwards when outside); ours
refines the best by least squares (twice) and counts its inliers again on all points,
pyRANSAC-3D does not refine; pyRANSAC-3D is a Python loop over numpy calls per hypothesis,
ours compiled.

As shipped (``perception_ms``, ``shipped_vs_pyransac3d``, the InlierIndex): the pipeline as
it runs, and the replay through ours as shipped (scoring 500 points) against pyRANSAC-3D at
numpy's default threads: not equal scoring work, named as such.

Beside them: Open3D ``segment_plane`` (planes only: no cylinder or sphere RANSAC, Algorithm 1
runs planes-only with it; no normals, scores on all subsampled points, least squares on the
best hypothesis' inliers; ``probability=1`` so it spends the whole budget as ours does; it
may use both cores: CPU time printed beside wall time). Two timings of the fitting: the
``primitives`` stage (Algorithm 1 over all segments) with each fitter — each fitter's fits
steer Algorithm 1 its own way, so the fitted points and the number of fits differ (both
printed) — and the replays. Wall and CPU time are both printed (the machine may be shared).

Last line: like_for_like_vs_pyransac3d=<replay, every point scored: pyRANSAC-3D ÷ ours>
perception_ms=<whole pipeline, ours as shipped, median wall ms>
shipped_vs_pyransac3d=<replay: pyRANSAC-3D ÷ ours as shipped, 500 points scored>
inlier_index=<ours> inlier_index_pyransac3d=<the pipeline with pyRANSAC-3D's fits>.
Target (issue 18): ≤ 40 ms per frame for the whole pipeline.
"""

from __future__ import annotations

import argparse
import functools
import random
import sys
import time
import warnings
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import open3d as o3d  # noqa: E402
import pyransac3d as pyrsc  # noqa: E402

from benchmarks._threads import blas_threads  # noqa: E402
from experiments import evaluation  # noqa: E402
from services.perception import ransac  # noqa: E402
from services.perception.pipeline import Perception, observation  # noqa: E402
from services.sim import capture  # noqa: E402
from services.sim.render import CameraRenderer  # noqa: E402
from services.sim.robots import ARMAR6  # noqa: E402
from services.sim.world import World, look_target  # noqa: E402

KINDS = ("fit_plane", "fit_cylinder", "fit_sphere")


def _mask(n: int, inliers) -> np.ndarray:
    m = np.zeros(n, bool)
    m[np.asarray(inliers, dtype=np.intp)] = True
    return m


# -- pyRANSAC-3D's fits, with Algorithm 1's signatures -------------------------------------------


def pyrsc_plane(X, N, rng, dist, cos_min, hypotheses=48):
    if len(X) < 3:
        return None
    eq, inl = pyrsc.Plane().fit(X, thresh=dist, maxIteration=hypotheses)
    if len(inl) == 0:
        return None
    return ransac.Fit("plane", _mask(len(X), inl), normal=np.asarray(eq[:3]), d=float(eq[3]))


def pyrsc_cylinder(X, N, rng, dist, cos_min, r_min, r_max, hypotheses=32):
    if len(X) < 10:
        return None
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c, a, r, inl = pyrsc.Cylinder().fit(X, thresh=dist, maxIteration=hypotheses)
    if len(inl) == 0 or not r_min < r < r_max:
        return None
    a = np.asarray(a, float)
    return ransac.Fit(
        "cylinder", _mask(len(X), inl), center=np.asarray(c, float), axis=a, radius=float(r)
    )


def pyrsc_sphere(X, N, rng, dist, cos_min, r_min, r_max, hypotheses=32):
    if len(X) < 10:
        return None
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c, r, inl = pyrsc.Sphere().fit(X, thresh=dist, maxIteration=hypotheses)
    if len(inl) == 0 or not r_min < r < r_max:
        return None
    return ransac.Fit("sphere", _mask(len(X), inl), center=np.asarray(c, float), radius=float(r))


# -- Open3D's plane fit --------------------------------------------------------------------------


def o3d_plane(X, N, rng, dist, cos_min, hypotheses=48):
    if len(X) < 3:
        return None
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(X))
    model, inl = pcd.segment_plane(dist, 3, hypotheses, probability=1.0)
    if len(inl) == 0:
        return None
    n = np.asarray(model[:3], float)
    norm = np.linalg.norm(n)
    return ransac.Fit("plane", _mask(len(X), inl), normal=n / norm, d=float(model[3]) / norm)


def _none(*args, **kwargs):
    return None


OURS = {k: getattr(ransac, k) for k in KINDS}
#: ours scoring every hypothesis on every point of the call, as pyRANSAC-3D does
OURS_ALL = {k: functools.partial(getattr(ransac, k), subset=None) for k in KINDS}
FITTERS = {
    "ours": OURS,
    "pyRANSAC-3D": dict(zip(KINDS, (pyrsc_plane, pyrsc_cylinder, pyrsc_sphere), strict=True)),
    "Open3D": dict(zip(KINDS, (o3d_plane, _none, _none), strict=True)),
}


@contextmanager
def patched(fitter: dict):
    """Algorithm 1's fitting step swapped for ``fitter`` (ours: left alone)."""
    if fitter is OURS:
        yield
        return
    with (
        mock.patch.object(ransac, "fit_plane", fitter["fit_plane"]),
        mock.patch.object(ransac, "fit_cylinder", fitter["fit_cylinder"]),
        mock.patch.object(ransac, "fit_sphere", fitter["fit_sphere"]),
    ):
        yield


class Fitting:
    """Algorithm 1's fitting step swapped for one fitter, recording each call's inputs (for
    the replay) and the points it was given."""

    def __init__(self, fitter: dict) -> None:
        self.fitter = fitter
        self.calls: list[tuple[str, tuple, dict]] = []
        self.points = 0

    def _wrap(self, kind: str):
        fn = self.fitter[kind]

        def fit(X, N, rng, *args, **kwargs):
            self.calls.append((kind, (X.copy(), N.copy(), *args), dict(kwargs)))
            self.points += len(X)
            return fn(X, N, rng, *args, **kwargs)

        return fit

    @contextmanager
    def active(self):
        with patched({k: self._wrap(k) for k in KINDS}):
            yield self


def seed_all(seed: int = 0) -> None:
    random.seed(seed)  # pyRANSAC-3D samples with the random module
    o3d.utility.random.seed(seed)


def run(perception: Perception, frame, fitter: dict, repeats: int, segments, label: str):
    """A warm run (recording the fitting calls), then ``repeats`` timed runs of the whole
    pipeline with ``fitter`` patched in (ours: nothing patched); medians."""
    seed_all()
    recorder = Fitting(fitter)
    with recorder.active():
        perception.perceive(frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera)
    total, cpu, stages, result = [], [], [], None
    for i in range(repeats):
        seed_all()
        with patched(fitter):
            t0, c0 = time.perf_counter(), time.process_time()
            result = perception.perceive(
                frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera
            )
            total.append((time.perf_counter() - t0) * 1e3)
            cpu.append((time.process_time() - c0) * 1e3)
        stages.append(result.timings_ms)
        print(f"\r  {label}: run {i + 1}/{repeats}", end="", file=sys.stderr, flush=True)
    print(file=sys.stderr)
    obs = observation(result, frame, 0, "bench", 3.0, perception.config.stride)
    scores = evaluation.score_primitives(segments, obs.primitives)
    return {
        "ms": float(np.median(total)),
        "cpu_ms": float(np.median(cpu)),
        "stages": {k: float(np.median([s[k] for s in stages])) for k in stages[0]},
        "fit_calls": len(recorder.calls),
        "fit_points": recorder.points,
        "calls": recorder.calls,
        "ii": scores.inlier_index,
        "oi": scores.overlapping_index,
        "n": len(obs.primitives),
        "kinds": {k: sum(p.kind == k for p in result.primitives) for k in ("plane", "box",
                                                                         "cylinder", "sphere")},
    }  # fmt: skip


def replay(calls, fitter: dict, repeats: int) -> dict[str, tuple[float, float]]:
    """The recorded fitting calls through ``fitter``: median wall and CPU ms per kind."""
    out: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in KINDS}
    for r in range(repeats + 1):  # the first is a warm-up
        seed_all()
        wall = dict.fromkeys(KINDS, 0.0)
        cpu = dict.fromkeys(KINDS, 0.0)
        for i, (kind, args, kwargs) in enumerate(calls):
            rng = np.random.default_rng(i)
            w, c = time.perf_counter(), time.process_time()
            fitter[kind](args[0], args[1], rng, *args[2:], **kwargs)
            wall[kind] += time.perf_counter() - w
            cpu[kind] += time.process_time() - c
        if r:
            for k in KINDS:
                out[k][0].append(wall[k] * 1e3)
                out[k][1].append(cpu[k] * 1e3)
    return {k: (float(np.median(w)), float(np.median(c))) for k, (w, c) in out.items()}


def replay_segment_plane(calls, repeats: int) -> tuple[float, float]:
    """Open3D's ``segment_plane`` alone on the recorded plane calls, each cloud built before
    the clock starts (its numpy → Vector3dVector copy left out): median wall and CPU ms."""
    planes = [
        (o3d.geometry.PointCloud(o3d.utility.Vector3dVector(args[0])), args[2],
         kwargs.get("hypotheses", args[4] if len(args) > 4 else 48))
        for kind, args, kwargs in calls if kind == "fit_plane"
    ]  # fmt: skip
    walls, cpus = [], []
    for r in range(repeats + 1):
        seed_all()
        w, c = time.perf_counter(), time.process_time()
        for pcd, dist, hypotheses in planes:
            pcd.segment_plane(dist, 3, hypotheses, probability=1.0)
        if r:
            walls.append((time.perf_counter() - w) * 1e3)
            cpus.append((time.process_time() - c) * 1e3)
    return float(np.median(walls)), float(np.median(cpus))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed runs of each (≥ 3)")
    args = parser.parse_args()
    repeats = max(3, args.repeats)

    world = World("tabletop_clutter", ARMAR6)
    world.look_at(look_target(world))
    renderer = CameraRenderer(world.model, 640, 480)
    frame, gt = capture.view(world, renderer, "head_rgbd", np.random.default_rng(0))
    renderer.close()
    segments = evaluation.labelled_points(gt, frame.depth, frame.intrinsics, frame.T_world_camera)

    perception = Perception()
    perception.warm_up()
    runs = {name: run(perception, frame, f, repeats, segments, name) for name, f in FITTERS.items()}
    ours = runs["ours"]
    calls = ours["calls"]
    print(
        f"{len(calls)} fitting calls of Algorithm 1 on {ours['fit_points']} subsampled points "
        f"in all (ours); medians of {repeats} warm runs each"
    )
    stages = {k: round(v, 1) for k, v in ours["stages"].items()}
    print(f"ours, stages (ms): {stages}")
    print(
        f"{'fitting by':12s} {'pipeline':>9s} {'CPU':>7s} {'primitives':>10s} {'calls':>6s} "
        f"{'points':>7s}  InlierIndex  Overlapping  primitives"
    )
    for name, r in runs.items():
        print(
            f"{name:12s} {r['ms']:7.1f}ms {r['cpu_ms']:5.1f}ms {r['stages']['primitives']:8.1f}ms "
            f"{r['fit_calls']:6d} {r['fit_points']:7d}  {r['ii']:11.3f}  {r['oi']:11.3f}  "
            f"{r['n']} {r['kinds']}"
        )
    prim = {name: r["stages"]["primitives"] for name, r in runs.items()}
    print(
        f"primitives stage (Algorithm 1, each fitter's own course; calls and points differ): "
        f"pyRANSAC-3D's fits ÷ ours ×{prim['pyRANSAC-3D'] / prim['ours']:.1f}, "
        f"Open3D's (planes only) ÷ ours ×{prim['Open3D'] / prim['ours']:.1f}"
    )
    counts = {k: sum(c[0] == k for c in calls) for k in KINDS}
    print(
        f"replay: ours' {len(calls)} fitting calls (identical points, thresholds, budgets) "
        "through each fitter, ms wall / CPU (÷ ours)"
    )
    base = replay(calls, OURS, repeats)
    totals = {}
    for name, fitter in FITTERS.items():
        t = base if name == "ours" else replay(calls, fitter, repeats)
        cells = []
        for k in KINDS:
            if fitter[k] is _none:
                cells.append(f"{k[4:]} —")
            else:
                cells.append(
                    f"{k[4:]} ×{counts[k]} {t[k][0]:6.1f}/{t[k][1]:6.1f} "
                    f"(×{t[k][0] / base[k][0]:.1f})"
                )
        totals[name] = sum(t[k][0] for k in KINDS if fitter[k] is not _none)
        print(f"  {name:12s} " + "   ".join(cells))
    wall, cpu = replay_segment_plane(calls, repeats)
    print(
        f"  {'Open3D':12s} plane ×{counts['fit_plane']} {wall:6.1f}/{cpu:6.1f} "
        f"(×{wall / base['fit_plane'][0]:.1f}) segment_plane alone, clouds built beforehand"
    )
    ours_all = sum(base[k][0] for k in KINDS)
    shipped = totals["pyRANSAC-3D"] / ours_all
    print(
        f"replay, all kinds: ours {ours_all:.1f} ms, pyRANSAC-3D {totals['pyRANSAC-3D']:.1f} ms "
        f"(×{shipped:.1f}: shipped_vs_pyransac3d, ours scoring {ransac.SUBSET} points); Open3D, "
        f"planes only: ×{totals['Open3D'] / base['fit_plane'][0]:.1f} on the plane calls"
    )
    # like for like: ours scoring every point, as pyRANSAC-3D does; one BLAS thread each
    with blas_threads(1) as held:
        equal = replay(calls, OURS_ALL, repeats)
        peer = replay(calls, FITTERS["pyRANSAC-3D"], repeats)
    ours_eq, peer_eq = (sum(t[k][0] for k in KINDS) for t in (equal, peer))
    cpu_eq, peer_cpu = (sum(t[k][1] for k in KINDS) for t in (equal, peer))
    like = peer_eq / ours_eq
    print(
        f"like for like, the same calls, every hypothesis scored on every point, one thread "
        f"each (numpy's OpenBLAS held to one: {held} libraries), ms wall / CPU:\n"
        + "\n".join(
            f"  {k[4:]:8s} ×{counts[k]:3d}: ours {equal[k][0]:6.1f}/{equal[k][1]:6.1f}  "
            f"pyRANSAC-3D {peer[k][0]:6.1f}/{peer[k][1]:6.1f}  (×{peer[k][0] / equal[k][0]:.1f})"
            for k in KINDS
        )
        + f"\n  all kinds: ours {ours_eq:.1f}/{cpu_eq:.1f}, pyRANSAC-3D {peer_eq:.1f}/"
        f"{peer_cpu:.1f}: ×{like:.1f} (like_for_like_vs_pyransac3d)"
    )
    print(
        f"like_for_like_vs_pyransac3d={like:.1f} perception_ms={ours['ms']:.1f} "
        f"shipped_vs_pyransac3d={shipped:.1f} inlier_index={ours['ii']:.3f} "
        f"inlier_index_pyransac3d={runs['pyRANSAC-3D']['ii']:.3f}"
    )


if __name__ == "__main__":
    main()
