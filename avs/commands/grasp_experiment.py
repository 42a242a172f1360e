"""``avs grasp-experiment``: thesis 5.4.2 in the sim: ARMAR-III drives past a table and grasps
a green cup it has to find, while moving, by position-based visual servoing, with the gaze
stabiliser on or off (``--compare``: both, printed as thesis Table 5.1). Writes
``DIR/metrics.json``, ``uncertainty.png`` (Fig. 5.12), ``flow.png`` and ``frames.png``; with
``--seeds N`` each seed goes to ``DIR/seed-<k>/`` and ``DIR/metrics.json`` holds all of them;
``--jobs N`` runs N of the runs at a time, each in a process of its own."""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from multiprocessing import get_context
from pathlib import Path

from avs.commands._args import positive_int
from avs.commands.gaze_experiment import _bar


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "grasp-experiment",
        help="grasping while moving, stabilised or not (thesis 5.4.2, Table 5.1, Fig. 5.12)",
        description=__doc__,
    )
    p.add_argument("--scene", default="grasping", help="scene name or MJCF file")
    p.add_argument(
        "--stabilize", choices=["on", "off"], default="on",
        help="the gaze stabiliser holds the fixation point (thesis 5.3) or the head stays put",
    )  # fmt: skip
    p.add_argument("--compare", action="store_true", help="run off and on, print Table 5.1")
    p.add_argument("--speed", type=float, default=0.15, help="platform speed, m/s")
    p.add_argument(
        "--sway", type=float, default=0.0,
        help="a sway of the body while driving: hip yaw rate amplitude, deg/s at 0.5 Hz",
    )  # fmt: skip
    p.add_argument(
        "--noise", choices=["on", "off"], default="on",
        help="the robot's sensor models (gyro, encoders, latency, odometry); off: exact state",
    )  # fmt: skip
    p.add_argument("--duration", type=float, default=24.0, help="s of simulated time at most")
    p.add_argument("--seed", type=int, default=0, help="first seed (sensor models, calibration)")
    p.add_argument("--seeds", type=positive_int, default=1, help="seeds to run, from --seed")
    p.add_argument(
        "--jobs", type=positive_int, default=1,
        help="runs at a time, each in a process of its own (a run keeps one core busy)",
    )  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.set_defaults(func=_run)


def _one(config, out: Path, label: str, bar: bool = True) -> tuple[dict, object]:
    """One run, its metrics.json written to ``out``; ``bar``: a progress bar on stderr (one run
    at a time), else a line when it is done."""
    from experiments.grasp import run_grasp, summarise

    start = time.monotonic()
    run = run_grasp(config, _bar(f"{label:>22}") if bar else None)
    if bar:
        print(file=sys.stderr)
    else:
        print(f"{label}: done in {time.monotonic() - start:.0f} s", file=sys.stderr, flush=True)
    metrics = summarise(run, config)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    return metrics, run


def table(off: list[dict], on: list[dict]) -> str:
    """Table 5.1's layout (medians over seeds): flow error unstabilised, stabilised, decrease;
    then grasps and when the cup's uncertainty met the task acuity."""
    import numpy as np

    def med(runs: list[dict], key: str, stat: str) -> float:
        return float(np.median([r[key][stat] for r in runs]))

    lines = [f"{'':<30}{'unstabilised':>14}{'stabilised':>12}{'decrease':>10}"]
    for stat in ("std", "mean", "max"):
        a, b = med(off, "flow_rmse_deg_s", stat), med(on, "flow_rmse_deg_s", stat)
        lines.append(f"{'flow RMSE ' + stat + ' (deg/s)':<30}{a:>14.2f}{b:>12.2f}"
                     f"{100 * (b - a) / a:>9.1f} %")  # fmt: skip
    a, b = med(off, "flow_rmse_all_deg_s", "mean"), med(on, "flow_rmse_all_deg_s", "mean")
    lines.append(f"{'  with gaze shifts, mean':<30}{a:>14.2f}{b:>12.2f}{100 * (b - a) / a:>9.1f} %")
    n = len(on)
    lines.append(f"{'grasped':<30}{sum(r['grasped'] for r in off):>11d}/{n}"
                 f"{sum(r['grasped'] for r in on):>9d}/{n}")  # fmt: skip

    def delay(r: dict) -> str:
        if r["acuity_reached_s"] is None or r["acuity_raised_s"] is None:
            return "never"
        return f"{r['acuity_reached_s'] - r['acuity_raised_s']:.1f}"

    lines.append(f"acuity met after it was raised, s: unstabilised {', '.join(map(delay, off))}"
                 f"; stabilised {', '.join(map(delay, on))}")  # fmt: skip
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    from experiments.grasp import GraspExperimentConfig
    from experiments.report import grasp_plots

    base = GraspExperimentConfig(
        scene=args.scene, speed=args.speed, sway=(args.sway, 0.5), sensors=args.noise == "on",
        duration=args.duration,
    )  # fmt: skip
    modes = {"unstabilised": False, "stabilised": True} if args.compare else {
        "stabilised" if args.stabilize == "on" else "unstabilised": args.stabilize == "on"
    }  # fmt: skip
    seeds = range(args.seed, args.seed + args.seeds)
    outs = {k: args.out if args.seeds == 1 else args.out / f"seed-{k}" for k in seeds}
    tasks = {
        (k, mode): (
            replace(base, stabilize=on, seed=k),
            outs[k] / ("on" if on else "off") if args.compare else outs[k],
            f"{mode} seed {k}",
        )
        for k in seeds
        for mode, on in modes.items()
    }
    if args.jobs > 1:  # spawned: a forked MuJoCo/EGL context is not to be shared
        with ProcessPoolExecutor(args.jobs, mp_context=get_context("spawn")) as pool:
            pending = {key: pool.submit(_one, *task, bar=False) for key, task in tasks.items()}
            done = {key: f.result() for key, f in pending.items()}
    else:
        done = {key: _one(*task) for key, task in tasks.items()}
    results: dict[str, list[dict]] = {m: [done[k, m][0] for k in seeds] for m in modes}
    for k in seeds:
        grasp_plots({m: done[k, m][1] for m in modes}, outs[k], base.acuity_grasp)
    summary = {m: (r[0] if args.seeds == 1 else r) for m, r in results.items()}
    args.out.mkdir(parents=True, exist_ok=True)
    if args.compare or args.seeds > 1:
        (args.out / "metrics.json").write_text(json.dumps(summary, indent=2))
    if args.compare:
        print(table(results["unstabilised"], results["stabilised"]))
    else:
        for mode, runs in results.items():
            for r in runs:
                f = r["flow_rmse_deg_s"]
                print(f"{mode}: grasped {r['grasped']}, first localised at "
                      f"{r['first_localised_s']} s, flow RMSE {f['mean']:.2f} ± {f['std']:.2f} "
                      f"deg/s (max {f['max']:.2f})")  # fmt: skip
    print(f"wrote {args.out}/metrics.json, uncertainty.png, flow.png, frames.png")
    return 0
