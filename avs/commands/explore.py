"""``avs explore``: one exploration episode with every service as a local process (sim in
lockstep, perception, scene memory, nbv, the explorer stepping the sim, over a loopback Zenoh
router; ``experiments/episode.py`` scores each view from outside): ``DIR/metrics.json``,
``f1.png``, ``unknown_voxels.png``, ``path_cost.png``, ``views_map.png`` and a self-contained
``report.html``. ``avs compare``: several strategies over several seeds, side by side (thesis
Fig. 4.8, 4.11, 4.12): per strategy the final views' support F1, unknown voxels and path cost
as the median over the seeds with its 95 % bootstrap interval, and which orderings of the
strategies the intervals support (apart) and which they leave unresolved
(``experiments/bootstrap.py``; ``DIR/metrics.json``: ``runs`` per strategy, ``summary``
{median, ci95, n} per strategy and metric, ``orderings``); with several fusion modes
(``--fusion pc,sg,pc+sg``) every strategy runs with each, runs are keyed ``strategy/fusion``,
and ``fusion_f1.png`` / ``fusion_f1.json`` give the support-graph F1 per view of each (median
and min-max over the seeds: Fig. 4.8)."""

from __future__ import annotations

import argparse
import json
import multiprocessing
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

from avs.commands._args import (
    FUSIONS,
    ROBOT_HELP,
    ROBOTS,
    add_console_arguments,
    fusion_list,
    positive_float,
    positive_int,
    scene_help,
)
from avs.console import log_to


def _episode_arguments(
    p: argparse.ArgumentParser, fusions: bool = False, out: Path | None = None
) -> None:
    p.add_argument("--scene", default="tabletop_occluded", help=scene_help())
    p.add_argument("--robot", default="armar6", choices=ROBOTS, help=ROBOT_HELP)
    p.add_argument(
        "--sampling", choices=["equidistant", "random", "topdown"], default="equidistant",
        help="the candidate views on the view sphere (thesis 4.3.1): evenly spread, at "
        "random, or from above",
    )  # fmt: skip
    if fusions:
        p.add_argument(
            "--fusion", type=fusion_list, default=["sg"], metavar="pc,sg,pc+sg",
            help="support-graph combination, or a comma list of them: every strategy runs with "
            "each, keyed strategy/fusion, and fusion_f1.png plots F1 per view (Fig. 4.8)",
        )  # fmt: skip
    else:
        p.add_argument(
            "--fusion", choices=FUSIONS, default="sg",
            help="how the views' support graphs combine (thesis 3.3): pc, the registered "
            "cloud perceived again; sg, the graphs fused; pc+sg, both",
        )  # fmt: skip
    p.add_argument("--views", type=positive_int, default=10, help="at most this many views (n)")
    p.add_argument("--voxel", type=positive_float, default=0.01, help="occupancy voxel, m")
    p.add_argument(
        "--ig-measure",
        choices=["volume", "rays"],
        default="volume",
        help="information gain: unknown voxels seen (volume) or Eq. 4.6's per-ray count",
    )
    p.add_argument(
        "--noise",
        choices=["on", "off"],
        default="on",
        help="the robot's sensor models in the sim: depth noise, gyro noise and bias, encoders, "
        "latency, odometry drift (off: the simulator's truth)",
    )
    p.add_argument(
        "--registration", choices=["on", "off"], default=None,
        help="the scene memory registers each frame against the map first (thesis A.5; "
        "default: as --noise)",
    )  # fmt: skip
    p.add_argument(
        "--out", type=Path, default=out, required=out is None,
        help="output directory" + (f" (default {out})" if out else ""),
    )  # fmt: skip
    add_console_arguments(p)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "explore",
        help="one exploration episode: all services, metrics, plots, report",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _episode_arguments(p, out=Path("runs/explore"))
    p.add_argument(
        "--strategy", choices=["utility", "occupancy", "random", "saliency"], default="utility",
        help="how the next view is chosen: utility (information gain against path cost, Eq. "
        "4.9), occupancy (unknown voxels only), random, saliency",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the sim's noise and sampling")
    p.add_argument(
        "--viewer", action="store_true",
        help="watch the episode live in rerun ('avs view'): the native viewer where there is "
        "a display, else the web viewer (its address is printed)",
    )  # fmt: skip
    p.add_argument(
        "--save-view", type=Path, metavar="FILE",
        help="record what 'avs view' shows of the episode to FILE (.rrd), headless",
    )  # fmt: skip
    p.set_defaults(func=_explore)
    c = sub.add_parser(
        "compare",
        help="strategies side by side over seeds (Fig. 4.8, 4.11, 4.12)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    _episode_arguments(c, fusions=True)
    c.add_argument(
        "--strategies", default="utility,occupancy,random",
        help="comma list of strategies (utility, occupancy, random, saliency)",
    )  # fmt: skip
    c.add_argument(
        "--seeds", type=positive_int, default=5,
        help="seeds per strategy (default 5: the fewest whose medians get a 95 %% interval)",
    )  # fmt: skip
    c.add_argument(
        "--jobs",
        type=positive_int,
        default=1,
        help="episodes run at once, each with its own router and services (an episode keeps "
        "about one core busy)",
    )
    c.set_defaults(func=_compare)


def _info(r) -> str:
    return (f"F1 {r.support_f1:.2f}  unknown {r.unknown_voxels}  "
            f"cost {r.accumulated_path_cost:.1f} s")  # fmt: skip


def run_episode(config, label: str, lines: bool = False, display=None) -> dict:
    """One episode; its progress as a task of ``display`` (a started rich Progress), or
    (``lines``, episodes running side by side in other processes) one line per view."""
    from experiments.episode import Episode

    if lines:

        def show(i: int, n: int, r) -> None:
            print(f"{label} view {i}/{n}  {_info(r)}", file=sys.stderr, flush=True)

        result = Episode(config, show).run().to_json()
        print(f"{label} terminated by {result['terminated_by']}", file=sys.stderr, flush=True)
        return result
    task = display.add_task(label, total=config.views, info="starting the services")

    def advance(i: int, n: int, r) -> None:
        display.update(task, completed=i, total=n, info=_info(r))

    result = Episode(config, advance).run().to_json()
    done = len(result["views"])
    display.update(task, completed=done, total=done or config.views,
                   info=f"terminated by {result['terminated_by']}")  # fmt: skip
    return result


def episode(config, label: str, verbose: bool = False) -> dict:
    """One episode in this process with the console of the long commands: a progress bar,
    the services' logs in ``config.out/logs`` (live on the console with ``verbose``)."""
    from avs.console import following, progress

    with following(config.out / "logs", verbose), progress() as display:
        return run_episode(config, label, display=display)


def _config(args: argparse.Namespace, **kw):
    from experiments.episode import EpisodeConfig

    kw.setdefault("fusion", args.fusion)
    return EpisodeConfig(
        scene=args.scene, robot=args.robot, sampling=args.sampling,
        views=args.views, voxel=args.voxel, ig_measure=args.ig_measure, out=args.out,
        noise=args.noise == "on", registration=(args.registration or args.noise) == "on", **kw,
    )  # fmt: skip


def write_outputs(
    out: Path, runs: dict[str, list[dict]], title: str, first: tuple[Path, ...] = ()
) -> Path:
    from experiments import report

    images = [*first, *report.series_plots(runs, out)]
    images.append(report.map_plot({k: v[0] for k, v in runs.items()}, out))
    tables = {f"{k} seed {e['seed']}": e for k, v in runs.items() for e in v}
    return report.html_report(title, images, tables, out)


def viewer_flags(live: bool, save: Path | None) -> tuple[str, ...] | None:
    """The ``avs view`` flags of ``--viewer`` / ``--save-view`` (None: no viewer)."""
    if not live and save is None:
        return None
    from avs.commands.view import has_display

    flags: tuple[str, ...] = ("--save", str(save)) if save is not None else ()
    if live:
        flags += ("--spawn",) if has_display() else ("--web", "--web-port", "0")
    return flags


def _explore(args: argparse.Namespace) -> int:
    from services.sim.scene import SceneError

    log_to(args.out / "logs", "explore")
    try:
        config = _config(args, strategy=args.strategy, seed=args.seed,
                         viewer=viewer_flags(args.viewer, args.save_view))  # fmt: skip
        result = episode(config, args.strategy, args.verbose)
        result["recording"] = str(args.save_view) if args.save_view else ""
    except SceneError as e:
        print(f"avs explore: {e}", file=sys.stderr)
        return 2
    (args.out / "metrics.json").write_text(json.dumps(result, indent=2))
    page = write_outputs(args.out, {args.strategy: [result]}, f"{args.scene}: {args.strategy}")
    summary(result)
    print(f"wrote {args.out / 'metrics.json'}, plots and {page}; logs in {args.out / 'logs'}")
    return 0


def summary(result: dict) -> None:
    last = result["views"][-1] if result["views"] else None
    if last is None:
        print("no view taken")
        return
    print(
        f"{result['scene']}: {len(result['views'])} views, terminated by "
        f"{result['terminated_by']}; support F1 {last['support_f1']:.2f}, unknown voxels "
        f"{last['unknown_voxels']}, path cost {last['accumulated_path_cost']:.1f} s, "
        f"InlierIndex {last['inlier_index']:.2f}, camera pose error "
        f"{1e3 * last['pose_error_m']:.1f} mm {last['pose_error_deg']:.2f}°"
    )


def _compare(args: argparse.Namespace) -> int:
    log_to(args.out / "logs", "compare")
    fusions = args.fusion
    base = _config(args, fusion=fusions[0])
    strategies = [s.strip() for s in args.strategies.split(",") if s.strip()]

    def key(strategy: str, fusion: str) -> str:  # one fusion: the strategy alone, as before
        return strategy if len(fusions) == 1 else f"{strategy}/{fusion}"

    def directory(strategy: str, fusion: str, seed: int) -> Path:
        return args.out / (f"{strategy}-{seed}" if len(fusions) == 1
                           else f"{strategy}-{fusion}-{seed}")  # fmt: skip

    episodes = [
        (key(strategy, fusion),
         replace(base, strategy=strategy, fusion=fusion, seed=seed,
                 out=directory(strategy, fusion, seed)))
        for fusion in fusions
        for strategy in strategies
        for seed in range(args.seeds)
    ]  # fmt: skip
    if args.jobs == 1:
        from avs.console import following, progress

        with following(args.out, args.verbose), progress() as display:
            results = [run_episode(c, f"{k} seed {c.seed}", display=display)
                       for k, c in episodes]  # fmt: skip
    else:  # fresh interpreters (spawn): no Zenoh session or thread crosses a fork
        spawn = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(args.jobs, mp_context=spawn) as pool:
            results = list(
                pool.map(
                    run_episode,
                    [c for _, c in episodes],
                    [f"{k} seed {c.seed}" for k, c in episodes],
                    [True] * len(episodes),
                )
            )
    runs: dict[str, list[dict]] = {}
    for (k, _), result in zip(episodes, results, strict=True):
        runs.setdefault(k, []).append(result)
    summary, orders = summarise_runs(runs)
    metrics = compare_json(runs, summary, orders)
    (args.out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    title, first = f"{args.scene}: strategies compared", ()
    if len(fusions) > 1:
        from experiments import report

        first = (report.fusion_plot(runs, args.out),)
        title = f"{args.scene}: strategies and fusion modes compared (Fig. 4.8)"
    page = write_outputs(args.out, runs, title, first)
    for line in summary_lines(runs, summary, orders):
        print(line)
    print(f"wrote {args.out / 'metrics.json'}, plots and {page}")
    return 0


#: the final view's metrics a comparison summarises: (key in a view, name, higher is better)
COMPARED = (
    ("support_f1", "F1", True),
    ("unknown_voxels", "unknown voxels", False),
    ("accumulated_path_cost", "path cost", False),
)


def summarise_runs(runs: dict[str, list[dict]]) -> tuple[dict, list]:
    """Per strategy and metric of the final views, the median over the seeds and its 95 %
    bootstrap interval (``experiments/bootstrap.py``); and every pair of strategies per metric, the
    better median first, with whether the intervals support that ordering."""
    from experiments.bootstrap import median_interval, orderings

    summary: dict[str, dict] = {}
    for k, episodes in runs.items():
        last = [e["views"][-1] for e in episodes if e["views"]]
        if last:
            summary[k] = {key: median_interval([v[key] for v in last]) for key, *_ in COMPARED}
    orders = [
        o
        for key, _, higher in COMPARED
        for o in orderings(key, {k: m[key] for k, m in summary.items()}, higher)
    ]
    return summary, orders


def compare_json(runs: dict[str, list[dict]], summary: dict, orders: list) -> dict:
    """``avs compare``'s metrics.json: every episode (``runs``, keyed by strategy, or
    strategy/fusion), the ``summary`` per key and metric ({median, ci95: [lo, hi], n}) and
    the ``orderings`` with whether the intervals support them."""
    from experiments.bootstrap import RESAMPLES, SEED

    return {
        "runs": runs,
        "summary": {k: {key: iv.to_json() for key, iv in m.items()} for k, m in summary.items()},
        "orderings": [o.to_json() for o in orders],
        "bootstrap": {"statistic": "median", "confidence": 0.95, "resamples": RESAMPLES,
                      "seed": SEED, "method": "percentile"},
    }  # fmt: skip


def summary_lines(runs: dict[str, list[dict]], summary: dict, orders: list) -> list[str]:
    """The console's summary: each metric's median and 95 % interval per key, then which
    orderings the intervals support and which they leave unresolved."""
    n = sorted({iv.n for m in summary.values() for iv in m.values()})
    lines = [f"final views, median [95 % bootstrap interval of the median] over "
             f"{'/'.join(map(str, n))} seeds:"]  # fmt: skip
    formats = {"support_f1": "{:.2f}", "unknown_voxels": "{:.0f}",
               "accumulated_path_cost": "{:.1f}"}  # fmt: skip
    units = {"accumulated_path_cost": " s"}
    for k, m in summary.items():
        parts = []
        for key, name, _ in COMPARED:
            f, iv, unit = formats[key], m[key], units.get(key, "")
            parts.append(f"{name} {f.format(iv.median)}{unit} "
                         f"[{f.format(iv.lo)}, {f.format(iv.hi)}]")  # fmt: skip
        lines.append(f"{k:16s} " + "  ".join(parts)
                     + f"  views {[len(e['views']) for e in runs[k]]}")  # fmt: skip
    from experiments.bootstrap import MIN_VALUES

    names = {key: (name, higher) for key, name, higher in COMPARED}
    unresolved = "not resolved (intervals overlap"
    if n and n[0] < MIN_VALUES:
        unresolved += f", or under {MIN_VALUES} seeds"
    for supported, title in ((True, "supported (intervals apart)"), (False, unresolved + ")")):
        said = []
        for o in orders:
            if o.supported != supported:
                continue
            name, higher = names[o.metric]
            equal = summary[o.better][o.metric].median == summary[o.worse][o.metric].median
            sign = "=" if equal else (">" if higher else "<")
            said.append(f"{name}: {o.better} {sign} {o.worse}")
        lines.append(f"{title}: " + ("; ".join(said) if said else "none"))
    return lines
