"""Plots and a self-contained HTML report of exploration episodes (thesis Fig. 4.8, 4.11,
4.12): support F1, unknown voxels and accumulated path cost over the views, and the chosen views
on a top-down map of the roi."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

SERIES = {
    "f1": ("support_f1", "support-graph F1 (Eq. 4.14)"),
    "unknown_voxels": ("unknown_voxels", "unknown voxels in the roi"),
    "path_cost": ("accumulated_path_cost", "accumulated path cost c(v), s (Eq. 4.9)"),
}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def series_plots(runs: dict[str, list[dict]], out: Path) -> list[Path]:
    """One plot per series; ``runs`` maps a label to its episodes (several seeds: median line
    and min-max band)."""
    from matplotlib.ticker import MaxNLocator

    plt = _plt()
    paths = []
    for name, (key, title) in SERIES.items():
        fig, ax = plt.subplots(figsize=(6.4, 3.6))
        for label, episodes in runs.items():
            n = max(len(e["views"]) for e in episodes)
            values = np.full((len(episodes), n), np.nan)
            for i, e in enumerate(episodes):
                v = [r[key] for r in e["views"]]
                values[i, : len(v)] = v
            x = np.arange(1, n + 1)
            ax.plot(x, np.nanmedian(values, axis=0), "o-", label=label)
            if len(episodes) > 1:
                ax.fill_between(x, np.nanmin(values, 0), np.nanmax(values, 0), alpha=0.2)
        ax.set_xlabel("view")
        ax.set_title(title)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.legend()
        paths.append(_save(fig, out / f"{name}.png"))
    paths.append(gain_plot(runs, out))
    return paths


def f1_spread(episodes: list[dict]) -> dict:
    """Support F1 per view over episodes (seeds): median, min and max of those that took each
    view, how many did, and each episode's series."""
    series = [[r["support_f1"] for r in e["views"]] for e in episodes]
    n = max((len(s) for s in series), default=0)
    values = np.full((len(series), n), np.nan)
    for i, s in enumerate(series):
        values[i, : len(s)] = s
    taken = np.isfinite(values).sum(axis=0)
    with np.errstate(all="ignore"):  # (no column is all-NaN: every view was taken once)
        median, lo, hi = (np.nanmedian(values, 0), np.nanmin(values, 0), np.nanmax(values, 0))
    return {
        "views": list(range(1, n + 1)),
        "median": [round(float(v), 4) for v in median],
        "min": [round(float(v), 4) for v in lo],
        "max": [round(float(v), 4) for v in hi],
        "episodes_at_view": [int(v) for v in taken],
        "seeds": [e["seed"] for e in episodes],
        "per_seed": [[round(float(v), 4) for v in s] for s in series],
        "final": [round(float(s[-1]), 4) for s in series if s],
    }


def fusion_plot(runs: dict[str, list[dict]], out: Path) -> Path:
    """Thesis Fig. 4.8: support-graph F1 per view of each strategy with each fusion mode (runs
    keyed ``strategy/fusion``): a colour per fusion mode, a line style per strategy, the median
    over the seeds as the line and their min-max as the band (each line shifted a little
    sideways so that equal ones stay visible). Writes ``fusion_f1.png`` and the numbers behind
    it, ``fusion_f1.json``."""
    from matplotlib.ticker import MaxNLocator

    plt = _plt()
    keys = list(runs)
    fusions = list(dict.fromkeys(k.rpartition("/")[2] for k in keys))
    strategies = list(dict.fromkeys(k.rpartition("/")[0] or k for k in keys))
    colours = dict(zip(fusions, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    styles = dict(zip(strategies, ["-", "--", ":", "-."] * 4, strict=False))
    markers = dict(zip(strategies, ["o", "s", "^", "D"] * 4, strict=False))
    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    numbers = {}
    for i, k in enumerate(keys):
        strategy, _, fusion = k.rpartition("/")
        strategy = strategy or k
        spread = f1_spread(runs[k])
        numbers[k] = {"strategy": strategy, "fusion": fusion, **spread}
        if not spread["views"]:
            continue
        x = np.array(spread["views"]) + 0.04 * (i - (len(keys) - 1) / 2)
        c = colours.get(fusion)
        ax.plot(x, spread["median"], ls=styles[strategy], marker=markers[strategy], ms=4,
                color=c, label=f"{strategy} {fusion.upper()}")  # fmt: skip
        if len(runs[k]) > 1:
            ax.fill_between(x, spread["min"], spread["max"], color=c, alpha=0.12)
    ax.set_xlabel("view")
    ax.set_ylabel("support-graph F1 (Eq. 4.14)")
    ax.set_ylim(-0.02, 1.05)
    ax.set_title("F1 per view by fusion mode (median, min-max over seeds)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8, loc="lower right")
    (out / "fusion_f1.json").write_text(json.dumps(numbers, indent=2))
    return _save(fig, out / "fusion_f1.png")


def gain_plot(runs: dict[str, list[dict]], out: Path) -> Path:
    """Predicted information gain of each view (the planner's, Eq. 4.6) against the gain it
    realised (the same measure, on what the camera then saw): a large gap means the planner
    reasons on a map the scene does not match."""
    from matplotlib.ticker import MaxNLocator

    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for label, episodes in runs.items():
        e = episodes[0]
        x = np.arange(1, len(e["views"]) + 1)
        line = ax.plot(x, [r["information_gain"] for r in e["views"]], "o-",
                       label=f"{label}: predicted")[0]  # fmt: skip
        ax.plot(x, [r.get("realised_gain", 0.0) for r in e["views"]], "s--",
                color=line.get_color(), label=f"{label}: realised")  # fmt: skip
    ax.set_xlabel("view")
    ax.set_title("information gain per view (first seed)")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize=8)
    return _save(fig, out / "information_gain.png")


def map_plot(episodes: dict[str, dict], out: Path) -> Path:
    """The roi from above, over the final map's obstacles (dark: occupied, light grey: seen),
    with each episode's platform poses, numbered, in the order taken."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5.5, 5.5))
    first = next(iter(episodes.values()))
    floor = Path(first.get("floor_png") or "/nonexistent")
    if floor.is_file():
        image = plt.imread(floor)
        x0, y0 = first["floor_origin"]
        w, h = image.shape[1] * first["floor_cell"], image.shape[0] * first["floor_cell"]
        ax.imshow(image, cmap="gray", vmin=0, vmax=1, extent=(x0, x0 + w, y0, y0 + h))
    (x0, y0, _), (x1, y1, _) = first["roi"]
    ax.add_patch(plt.Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, ls="--", label="roi"))
    cx, cy, _ = first["centre"]
    ax.plot([cx], [cy], "k+", ms=12)
    for label, e in episodes.items():
        b = np.array([r["base"] for r in e["views"]])
        if not len(b):
            continue
        line = ax.plot(b[:, 0], b[:, 1], "o", alpha=0.8, label=label)[0]
        driven = [p for r in e["views"] for p in r.get("trajectory", [])]
        if driven:
            d = np.array(driven)
            ax.plot(d[:, 0], d[:, 1], "-", lw=1, color=line.get_color(), alpha=0.7)
        for i, (x, y, yaw) in enumerate(b):
            ax.annotate(str(i + 1), (x, y), textcoords="offset points", xytext=(4, 4))
            ax.arrow(x, y, 0.2 * np.cos(yaw), 0.2 * np.sin(yaw), width=0.01, color=line.get_color())
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title("chosen views (platform poses)")
    ax.legend(loc="best")
    return _save(fig, out / "views_map.png")


def html_report(title: str, images: list[Path], tables: dict[str, dict], out: Path) -> Path:
    """report.html with the images inlined (base64), one summary table per episode."""
    parts = [f"<!doctype html><meta charset=utf-8><title>{html.escape(title)}</title>",
             "<style>body{font-family:sans-serif;max-width:1000px;margin:2em auto}"
             "img{max-width:100%}td,th{padding:2px 8px;text-align:right}</style>",
             f"<h1>{html.escape(title)}</h1>"]  # fmt: skip
    for img in images:
        data = base64.b64encode(img.read_bytes()).decode()
        parts.append(f'<p><img alt="{img.stem}" src="data:image/png;base64,{data}"></p>')
    cols = ["view", "support_precision", "support_recall", "support_f1", "vertex_precision",
            "bodies_merged", "unknown_voxels", "information_gain", "realised_gain", "path_cost",
            "accumulated_path_cost", "inlier_index", "overlapping_index", "planning_s"]  # fmt: skip
    for label, e in tables.items():
        parts.append(f"<h2>{html.escape(label)}</h2><p>terminated by {e['terminated_by']}</p>")
        parts.append("<table><tr>" + "".join(f"<th>{c}</th>" for c in cols) + "</tr>")
        for r in e["views"]:
            cells = "".join(
                f"<td>{r.get(c, 0):.3f}</td>"
                if isinstance(r.get(c, 0), float)
                else f"<td>{r.get(c, '')}</td>"
                for c in cols
            )
            parts.append(f"<tr>{cells}</tr>")
        parts.append("</table>")
    edges = {k: v["final_support_edges"] for k, v in tables.items()}
    parts.append(f"<h2>final support edges</h2><pre>{html.escape(json.dumps(edges))}</pre>")
    path = out / "report.html"
    path.write_text("\n".join(parts))
    return path


def gaze_plots(modes: dict[str, dict], out: Path) -> list[Path]:
    """The gaze experiment over time (thesis Fig. 5.10): ``flow.png`` (optical-flow error per
    frame pair, deg/s), ``blur.png`` (Crete et al. blur per frame) and ``brightness.png`` (each
    frame's mean luma: what the exposure made of the view), one line per mode (stabilised /
    unstabilised) and object run."""
    plt = _plt()
    paths = []
    for name, attr, title in (
        ("flow", "flow", "optical-flow error, deg/s (Farnebäck RMSE)"),
        ("blur", "blur", "perceptual blur (Crete et al. 2007), 0 sharp … 1 blurred"),
        ("brightness", "brightness", "frame brightness, mean luma 0-255"),
    ):
        fig, ax = plt.subplots(figsize=(6.4, 3.6))
        for mode, runs in modes.items():
            for obj, run in runs.items():
                values = getattr(run, attr)
                t = run.times[-len(values) :]
                ax.plot(t, values, lw=1, label=f"{mode}, {obj}")
        ax.set_xlabel("time, s")
        ax.set_title(title)
        ax.legend(fontsize=8)
        paths.append(_save(fig, out / f"{name}.png"))
    return paths


def grasp_plots(runs: dict[str, object], out: Path, acuity: float) -> list[Path]:
    """The grasping-while-moving experiment (thesis 5.4.2): ``uncertainty.png`` (Fig. 5.12: σ of
    the cup's localisation, Eq. 5.2, over time, with the raised task acuity and when it was
    raised), ``flow.png`` (optical-flow error per frame pair; gaze shifts marked) and
    ``frames.png`` (a strip of the left foveal camera, one row per mode). ``runs``: mode →
    ``GraspRun``."""
    plt = _plt()
    paths = []
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for mode, run in runs.items():
        if run.uncertainty:
            t, s = np.array(run.uncertainty).T
            line = ax.plot(t, 1e3 * s, lw=1.2, label=mode)[0]
            if run.acuity_raised_s is not None:
                ax.axvline(run.acuity_raised_s, color=line.get_color(), ls=":", lw=1)
    ax.axhline(1e3 * acuity, color="k", ls="--", lw=1, label="task acuity when grasping")
    ax.set_yscale("log")
    ax.set_xlabel("time, s (dotted: the servo raises the cup's acuity)")
    ax.set_ylabel("σ = det(Σ)^(1/6), mm")
    ax.set_title("cup localisation uncertainty (Eq. 5.2)")
    ax.legend(fontsize=8)
    paths.append(_save(fig, out / "uncertainty.png"))

    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    for mode, run in runs.items():
        ax.plot(run.times[1:], run.flow, lw=0.8, label=mode)
    shifts = next(iter(runs.values())).targets
    for t, _ in shifts:
        ax.axvline(t, color="0.8", lw=0.5, zorder=0)
    ax.set_xlabel("time, s (grey: gaze shifts of the first run)")
    ax.set_title("optical-flow error, deg/s (Farnebäck RMSE)")
    ax.legend(fontsize=8)
    paths.append(_save(fig, out / "flow.png"))

    rows = []
    for run in runs.values():
        frames = [f for _, f in run.strip][:8]
        if frames:
            frames += [np.zeros_like(frames[0])] * (8 - len(frames))
            rows.append(np.hstack([f[::4, ::4] for f in frames]))
    if rows:
        fig, ax = plt.subplots(figsize=(12, 1.3 * len(rows)))
        ax.imshow(np.vstack(rows))
        ax.set_axis_off()
        ax.set_title(" / ".join(f"row {i + 1}: {m}" for i, m in enumerate(runs))
                     + " — left foveal camera, one frame a second", fontsize=9)  # fmt: skip
        paths.append(_save(fig, out / "frames.png"))
    return paths
