"""Live exploration against the lockstep episode (issue 41): tabletop_occluded and
``--scenes`` − 1 generated table-top scenes (seeds 1000, 1001, …; ``avs scene generate``), each
explored both ways, one after the other on the same machine:

- **lockstep**: the CLI episode (``avs explore --scene S --views V``,
  ``experiments/episode.py``): the explorer service steps the sim and holds after each view;
  the episode's evaluator scores it (the sim's segmentation of each view).
  Time to F1 ≥ 0.9: from the services' start to the view whose score first reached it.
- **live**: ``avs up --explore --scene S --views V`` as a user starts it (no ``AVS_*`` variable
  passed on), on the wall clock with the sensor models, view registration and the gaze
  stabiliser; this script is an outside client: every ``--every`` seconds it scores what the
  running system holds (``avs score``'s evaluation: the scene memory's model and registered
  cloud against the sim's ground truth) until ``explore/status`` says the episode is done
  (then once more), or ``--timeout``. Time to F1 ≥ 0.9: from ``avs up``'s start to the first
  score that reached it (so up to ``--every`` late; the scoring itself takes a share of the
  machine meanwhile).

Both count the same thing, the honest support-graph F1 (every perceived edge judged), with two
labellings of the points (lockstep: per-pixel segmentation; live: the ground truth's body
boxes, ``evaluation.label_by_boxes``). A run that fails counts as F1 0 and is named.

Writes ``OUT/live_explore.json`` and ``OUT/live_explore.png`` (F1 over wall-clock time per
scene, both ways); progress on stderr. The last line:

scenes=<n> crashed=<n> lockstep_f1_mean=<x> live_f1_mean=<x> time_to_f1_09_s_median=<x>
lockstep_time_to_f1_09_s_median=<x>

Targets (issue 41): live_f1_mean ≥ lockstep_f1_mean − 0.05, time_to_f1_09_s_median ≤ 180 (live),
no scene crashed.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._loopback import user_environment  # noqa: E402
from services.sim.generate import generate  # noqa: E402

SCENE = "tabletop_occluded"


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def scenes(n: int, first_seed: int, out: Path) -> list[tuple[str, str]]:
    """(name, scene argument): tabletop_occluded, then generated scenes written under OUT."""
    chosen = [(SCENE, SCENE)]
    for seed in range(first_seed, first_seed + n - 1):
        path = out / "scenes" / f"scene_{seed}.xml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(generate(seed).text)
        chosen.append((f"scene_{seed}", str(path)))
    return chosen


def lockstep(scene: str, views: int, out: Path) -> dict:
    """The CLI episode, in this process; F1 per view with its time since the services' start."""
    from experiments.episode import Episode, EpisodeConfig

    curve: list[tuple[float, float]] = []
    t0 = time.monotonic()

    def progress(i: int, n: int, r) -> None:
        curve.append((time.monotonic() - t0, r.support_f1))
        print(f"  lockstep view {i}/{n}: F1 {r.support_f1:.2f}", file=sys.stderr, flush=True)

    result = Episode(EpisodeConfig(scene=scene, views=views, out=out), progress).run()
    return {"f1": curve[-1][1] if curve else 0.0, "views": len(result.views),
            "reason": result.terminated_by, "curve": curve,
            "seconds": time.monotonic() - t0}  # fmt: skip


def live(scene: str, views: int, out: Path, every: float, timeout: float) -> dict:
    """``avs up --explore`` as a user starts it, scored from outside until it is done."""
    import zenoh

    from avs.commands.score import score
    from schemas import ExploreStatus, Keys, decode

    keys, port = Keys(), _free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    command = [sys.executable, "-m", "avs.cli", "up", "--explore", "--scene", scene,
               "--views", str(views), "--listen", endpoint,
               "--data-dir", str(out / "data")]  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    log = open(out / "avs-up.log", "w")  # noqa: SIM115 (closed below)
    t0 = time.monotonic()
    up = subprocess.Popen(command, env=user_environment(), stdout=log, stderr=subprocess.STDOUT,
                          cwd=ROOT)  # fmt: skip
    curve: list[tuple[float, float]] = []
    statuses: list[ExploreStatus] = []
    row: dict = {"command": " ".join(command[2:])}
    try:
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        deadline = time.monotonic() + 60
        while True:  # the router listening
            try:
                session = zenoh.open(conf)
                break
            except zenoh.ZError:
                if time.monotonic() > deadline or up.poll() is not None:
                    raise RuntimeError("avs up did not start") from None
                time.sleep(0.5)
        with session:
            session.declare_subscriber(
                keys.explore_status(),
                lambda s: statuses.append(decode(s.payload.to_bytes(), ExploreStatus)),
            )
            done = False
            while time.monotonic() - t0 < timeout and not done and up.poll() is None:
                time.sleep(every)
                done = bool(statuses) and statuses[-1].phase == "done"
                try:
                    s = score(session, keys, 30.0)
                except SystemExit as e:  # nothing answered yet (the services starting)
                    print(f"  live: {e}", file=sys.stderr, flush=True)
                    continue
                curve.append((time.monotonic() - t0, s["support_f1"]))
                phase = statuses[-1].phase if statuses else "starting"
                view = statuses[-1].view if statuses else 0
                print(f"  live {curve[-1][0]:5.0f} s: {phase} view {view}, "
                      f"F1 {s['support_f1']:.2f}", file=sys.stderr, flush=True)  # fmt: skip
            end = statuses[-1] if statuses else None
            row |= {"views": end.view if end else 0,
                    "reason": end.reason if end and end.phase == "done" else "timeout"}  # fmt: skip
    finally:
        up.send_signal(signal.SIGINT)
        try:
            up.wait(60)
        except subprocess.TimeoutExpired:
            up.kill()
        log.close()
    return row | {"f1": curve[-1][1] if curve else 0.0, "curve": curve,
                  "seconds": time.monotonic() - t0}  # fmt: skip


def time_to(curve: list[tuple[float, float]], f1: float = 0.9) -> float | None:
    return next((t for t, f in curve if f >= f1), None)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for i, r in enumerate(rows):
        colour = f"C{i % 10}"
        for way, style in (("lockstep", "--"), ("live", "-")):
            curve = r.get(way, {}).get("curve") or []
            if curve:
                t, f = zip(*curve, strict=True)
                ax.step(t, f, style, where="post", color=colour,
                        label=f"{r['scene']} {way}")  # fmt: skip
    ax.axhline(0.9, color="grey", lw=0.8)
    ax.set_xlabel("wall-clock time since the services started (s)")
    ax.set_ylabel("support F1")
    ax.set_ylim(-0.02, 1.02)
    ax.set_title("Exploration, lockstep (dashed) and live (solid)")
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenes", type=int, default=5, help="tabletop_occluded + N-1 generated")
    p.add_argument("--first-seed", type=int, default=1000)
    p.add_argument("--views", type=int, default=6)
    p.add_argument("--every", type=float, default=5.0, help="live: seconds between scores")
    p.add_argument("--timeout", type=float, default=300.0, help="live: seconds per scene")
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "live_explore")
    args = p.parse_args()
    os.environ.setdefault("MUJOCO_GL", "egl")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name, scene in scenes(args.scenes, args.first_seed, args.out):
        row: dict = {"scene": name, "errors": []}
        for way in ("lockstep", "live"):
            print(f"{name} {way} …", file=sys.stderr, flush=True)
            where = args.out / name / way
            try:
                row[way] = (
                    lockstep(scene, args.views, where)
                    if way == "lockstep"
                    else live(scene, args.views, where, args.every, args.timeout)
                )
            except Exception as e:  # a crash is a result: named, F1 0
                row[way] = {"f1": 0.0, "curve": [], "views": 0, "reason": "crashed"}
                row["errors"].append(f"{way}: {type(e).__name__}: {e}")
        for way in ("lockstep", "live"):
            row[way]["time_to_f1_09_s"] = time_to(row[way]["curve"])
        rows.append(row)
        lk, lv = row["lockstep"], row["live"]
        print(f"{name}: lockstep F1 {lk['f1']:.2f} ({lk['views']} views, F1 ≥ 0.9 at "
              f"{lk['time_to_f1_09_s']}), live F1 {lv['f1']:.2f} ({lv['views']} views, "
              f"{lv.get('reason')}, F1 ≥ 0.9 at {lv['time_to_f1_09_s']})", flush=True)  # fmt: skip
    crashed = sum(bool(r["errors"]) for r in rows)
    times = [r["live"]["time_to_f1_09_s"] for r in rows]
    lock_times = [r["lockstep"]["time_to_f1_09_s"] for r in rows]

    def median(ts: list[float | None]) -> float:  # never reached counts as infinitely late
        return float(np.median([t if t is not None else np.inf for t in ts]))

    summary = {
        "scenes": len(rows),
        "crashed": crashed,
        "lockstep_f1_mean": round(float(np.mean([r["lockstep"]["f1"] for r in rows])), 3),
        "live_f1_mean": round(float(np.mean([r["live"]["f1"] for r in rows])), 3),
        "time_to_f1_09_s_median": round(median(times), 1),
        "lockstep_time_to_f1_09_s_median": round(median(lock_times), 1),
    }
    (args.out / "live_explore.json").write_text(json.dumps({"summary": summary, "rows": rows},
                                                           indent=1))  # fmt: skip
    plot(rows, args.out / "live_explore.png")
    print(f"wrote {args.out / 'live_explore.json'} and {args.out / 'live_explore.png'}")
    print(" ".join(f"{k}={v}" for k, v in summary.items()))


if __name__ == "__main__":
    main()
