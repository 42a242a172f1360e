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
#: what each plot's axes show, under it in the report (by the image's name)
CAPTIONS = {
    "f1": "Support-graph F1 (Eq. 4.14-4.16) of the fused model against the scene's truth after "
    "each view (x: views in the order taken, numbered as in the table; y: 0 to 1). Several "
    "seeds: the line is their median, the band their range.",
    "unknown_voxels": "Voxels of the region of interest still unknown after each view (the "
    "map's unknown cells inside the roi; fewer is better).",
    "path_cost": "Accumulated path cost c(v) (Eq. 4.9): the time, in seconds, the platform and "
    "the head took to reach the views so far.",
    "information_gain": "Information gain per view (Eq. 4.6, in voxels of the volume measure, "
    "rays for the ray measure): what the planner predicted beside what the view then realised "
    "by the same measure. Log scale: the first view starts from nothing known and realises "
    "every voxel it sees, in and around the roi, orders of magnitude more than the later ones.",
    "views_map": "The final map from above (dark: occupied between 5 cm and 2 m, light grey: "
    "seen; x and y in metres), the roi dashed, the platform poses numbered in the order taken, "
    "each with the head camera's horizontal field of view.",
    "fused_scene": "The fused model at the end, what meets the roi (dashed): each primitive "
    "as a solid in its colour (planes and boxes as their oriented boxes, cylinders and spheres "
    "as fitted), each body of the scene labelled once at its largest primitive ('#id': a "
    "primitive that matched no body), from a fixed viewpoint.",
    "support_graph": "The fused support graph (thesis 3.2.2, 3.3.1): an arrow from supporter "
    "to supported with occ(e), the views it was seen in; green: the truth has it, red: a false "
    "positive, grey: outside the roi (not judged), dashed: an edge of the truth not found. "
    "Amber nodes: no support found and nothing seen under them yet (unresolved); red: unstable.",
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
        if key == "support_f1":
            ax.set_ylim(-0.02, 1.05)
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
    ax.set_ylabel("voxels")
    ax.set_yscale("symlog", linthresh=100)
    several = any(len(episodes) > 1 for episodes in runs.values())
    ax.set_title("information gain per view" + (" (each strategy's first seed)" if several else ""))
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
        hfov = np.radians(e.get("camera_hfov_deg") or 0.0)
        for r in e["views"]:
            T = np.asarray(r.get("camera_pose_used") or np.zeros((0, 0)))
            if hfov <= 0 or T.shape != (4, 4):
                continue
            eye, forward = T[:2, 3], T[:2, 2]  # the optical axis (z), seen from above
            if np.linalg.norm(forward) < 1e-6:
                continue
            heading = np.arctan2(forward[1], forward[0])
            reach = 0.3 + np.linalg.norm(np.asarray(first["centre"][:2]) - eye)
            sides = [eye + reach * np.array([np.cos(heading + s), np.sin(heading + s)])
                     for s in (-hfov / 2, hfov / 2)]  # fmt: skip
            wedge = np.array([sides[0], eye, sides[1]])
            ax.plot(wedge[:, 0], wedge[:, 1], "-", lw=0.7, color=line.get_color(), alpha=0.6)
    ax.set_aspect("equal")
    ax.set_xlabel("x, m")
    ax.set_ylabel("y, m")
    ax.set_title("chosen views (platform poses)")
    ax.legend(loc="best")
    return _save(fig, out / "views_map.png")


def _img(path: Path, alt: str, cls: str = "") -> str:
    """An <img> with the file inlined (the report is one self-contained file)."""
    mime = "image/jpeg" if path.suffix.lower() in (".jpg", ".jpeg") else "image/png"
    data = base64.b64encode(path.read_bytes()).decode()
    c = f' class="{cls}"' if cls else ""
    return f'<img{c} alt="{html.escape(alt)}" src="data:{mime};base64,{data}">'


def _figure(path: Path, name: str | None = None) -> str:
    """The image with the caption of ``name`` (default: its file's name) from ``CAPTIONS``."""
    text = CAPTIONS.get(name or path.stem, "")
    return (
        f"<figure>{_img(path, path.stem)}"
        + (f"<figcaption>{html.escape(text)}</figcaption>" if text else "")
        + "</figure>"
    )


def summary_rows(e: dict) -> list[tuple[str, str]]:
    """The figures a reader wants first: how the episode ran, why it stopped, where it ended."""
    last = e["views"][-1] if e["views"] else {}
    why = e.get("terminated_by", "") + (f": {e['termination_detail']}"
                                        if e.get("termination_detail") else "")  # fmt: skip
    rows = [
        ("scene", e.get("scene", "")), ("robot", e.get("robot", "")),
        ("strategy", f"{e.get('strategy', '')}, {e.get('sampling', '')} sampling, seed "
                     f"{e.get('seed', '')}"),
        ("fusion", e.get("fusion", "")),
        ("sensor models", "on (noise, drift)" if e.get("noise", True) else "off (the truth)"),
        ("view registration", "on" if e.get("registration", True) else "off"),
        ("views", str(len(e["views"]))), ("stopped by", why),
    ]  # fmt: skip
    if last:
        rows += [
            ("support F1 (precision, recall)", f"{last['support_f1']:.2f} "
             f"({last['support_precision']:.2f}, {last['support_recall']:.2f})"),
            ("unknown voxels in the roi", f"{last['unknown_voxels']:,}"),
            ("path cost", f"{last['accumulated_path_cost']:.1f} s"),
            ("InlierIndex", f"{last['inlier_index']:.2f}"),
            ("camera pose error (last view)", f"{1e3 * last.get('pose_error_m', 0.0):.1f} mm, "
             f"{last.get('pose_error_deg', 0.0):.2f}°"),
        ]  # fmt: skip
    if e.get("recording"):
        rows.append(
            (
                "recording",
                f"rerun {e['recording']}  (the viewer AVS installs in .venv/bin; "
                "every stream of the episode)",
            )
        )
    return rows


#: the views table: header, unit, and how a view's record makes the cell
VIEW_COLUMNS = (
    ("view", "", lambda r: str(r["view"] + 1)),
    ("support F1", "(P / R)", lambda r: f"{r['support_f1']:.2f} "
     f"({r['support_precision']:.2f} / {r['support_recall']:.2f})"),
    ("unknown", "voxels", lambda r: f"{r['unknown_voxels']:,}"),
    ("gain predicted", "voxels", lambda r: f"{r['information_gain']:,.0f}"),
    ("gain realised", "voxels", lambda r: f"{r.get('realised_gain', 0.0):,.0f}"),
    ("path cost", "s (total)",
     lambda r: f"{r['path_cost']:.1f} ({r['accumulated_path_cost']:.1f})"),
    ("pose error", "mm / °", lambda r: f"{1e3 * r.get('pose_error_m', 0.0):.1f} / "
     f"{r.get('pose_error_deg', 0.0):.2f}"),
    ("registration", "", lambda r: r.get("registration", "") or "off"),
    ("planning", "s", lambda r: f"{r['planning_s']:.1f}"),
)  # fmt: skip

STYLE = (
    "body{font-family:system-ui,sans-serif;max-width:1180px;margin:1.5em auto;padding:0 1em;"
    "color:#222}img{max-width:100%;height:auto}figure{margin:1em 0}"
    "figcaption{font-size:0.85em;color:#555;max-width:760px}"
    "table{border-collapse:collapse;font-size:0.85em}td,th{padding:3px 8px;"
    "border-bottom:1px solid #ddd;vertical-align:middle}th{text-align:left;background:#f3f3f3}"
    "td.n{text-align:right;white-space:nowrap}table.summary td:first-child{color:#555}"
    ".pair{display:flex;flex-wrap:wrap;gap:1em}.pair figure{flex:1 1 520px;min-width:0}"
    "img.thumb{width:160px;display:block}code{background:#f3f3f3;padding:1px 4px}"
)


def episode_figures(e: dict, out: Path, tag: str) -> list[tuple[str, Path | str]]:
    """The fused-scene rendering and the support graph of episode ``e`` (files ``NAME{tag}``
    in ``out``); where one cannot be drawn, why (a string) in its place."""
    from experiments import scene_figures

    made: list[tuple[str, Path | str]] = []
    prims = e.get("final_primitives") or []
    for name, draw in (
        ("fused_scene", lambda: scene_figures.scene_image(prims, e["roi"], out)),
        ("support_graph", lambda: scene_figures.support_graph_image(
            prims, e.get("final_support") or [], e.get("final_missed") or [], out)),
    ):  # fmt: skip
        try:
            path = draw()
            made.append((name, path.rename(out / f"{name}{tag}.png")))
        except Exception as err:  # the report goes on without it, and says why
            made.append((name, f"{name}: not drawn ({type(err).__name__}: {err})"))
    return made


def html_report(title: str, images: list[Path], tables: dict[str, dict], out: Path) -> Path:
    """report.html, one self-contained file (images inlined): per episode a summary (the
    set-up, why it stopped, the final figures), the fused scene rendered and its support graph
    drawn (of the first seed only, where seeds are compared), the views with their colour
    images; then the plots, each with its caption."""
    parts = [f"<!doctype html><meta charset=utf-8><title>{html.escape(title)}</title>",
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             f"<style>{STYLE}</style>", f"<h1>{html.escape(title)}</h1>"]  # fmt: skip
    first_seed = min((e.get("seed", 0) for e in tables.values()), default=0)
    for i, (label, e) in enumerate(tables.items()):
        parts.append(f"<h2>{html.escape(label)}</h2><table class=summary>")
        parts += [f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>"
                  for k, v in summary_rows(e)]  # fmt: skip
        parts.append("</table>")
        drawn = e.get("final_primitives") or e.get("final_support") or e.get("final_missed")
        if drawn and e.get("seed", 0) == first_seed:  # (compared: each strategy's first seed)
            figures = episode_figures(e, out, "" if len(tables) == 1 else f"_{i}")
            parts.append('<div class="pair">')
            for name, f in figures:
                parts.append(_figure(f, name) if isinstance(f, Path)
                             else f"<p>{html.escape(f)}</p>")  # fmt: skip
            parts.append("</div>")
        head = "".join(f"<th>{html.escape(h)}<br><small>{html.escape(u)}</small></th>"
                       for h, u, _ in VIEW_COLUMNS)  # fmt: skip
        parts.append(f"<h3>views</h3><table><tr>{head}<th>colour image</th></tr>")
        for r in e["views"]:
            cells = "".join(f'<td class="n">{html.escape(cell(r))}</td>'
                            for _, _, cell in VIEW_COLUMNS)  # fmt: skip
            thumb = Path(e.get("out") or out) / r["rgb"] if r.get("rgb") else None
            shown = thumb is not None and thumb.is_file()
            image = _img(thumb, f"view {r['view'] + 1}", "thumb") if shown else ""
            parts.append(f"<tr>{cells}<td>{image}</td></tr>")
        parts.append("</table>")
    parts.append('<h2>plots</h2><div class="pair">')
    parts += [_figure(img) for img in images]
    parts.append("</div>")
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
