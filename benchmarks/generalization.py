"""AVS on scenes nobody here wrote: ``--scenes N`` generated table-top scenes (seeds 1000,
1001, …; ``avs scene generate``), each run through ``avs perceive --json`` (one view from
robot_start, turning toward the table first where it must) and ``avs explore --strategy
utility --fusion sg --views 6``, both as the user runs them (separate processes).

Prints one row per scene and a summary; writes ``DIR/generalization.json`` and
``DIR/generalization.png`` (final support F1 and InlierIndex per scene). A scene whose run
crashes counts as F1 0 in the means; ``inlier_index_mean`` is the mean of each episode's final
InlierIndex. Support F1 is the honest edge F1 (experiments/evaluation.py: every perceived edge
counts).

Last line: scenes=<n> crashed=<n> ended_at_view1=<n> f1_view1_mean=<x> f1_final_mean=<x>
f1_final_p10=<x> inlier_index_mean=<x>
Targets (issue 13): 0 crashed, 0 ended at view 1, f1_final_mean ≥ 0.85, f1_final_p10 ≥ 0.6.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from services.sim.generate import generate, heading_offset  # noqa: E402


def _avs(args: list[str], timeout: float) -> subprocess.CompletedProcess:
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"))
    return subprocess.run(
        [sys.executable, "-m", "avs.cli", "--log-level", "WARNING", *args],
        capture_output=True, text=True, timeout=timeout, cwd=ROOT, env=env,
    )  # fmt: skip


def _last_line(text: str) -> str:
    lines = [line for line in text.strip().splitlines() if line.strip()]
    return lines[-1][:200] if lines else ""


def run_scene(
    seed: int, out: Path, views: int, noise: str = "on", registration: str | None = None
) -> dict:
    """Generate, perceive and explore one scene; what went wrong goes into ``error``."""
    scene = generate(seed)
    path = out / "scenes" / f"scene_{seed}.xml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(scene.text)
    row: dict = {
        "seed": seed,
        "objects": len(scene.objects),
        "arrangements": [str(a) for a in scene.arrangements],
        "facing_away": heading_offset(scene.robot_start, scene.table) > math.radians(90),
        "errors": [],
    }
    t0 = time.perf_counter()
    p = _avs(["perceive", "--scene", str(path), "--json"], 300)
    if p.returncode == 0:
        d = json.loads(p.stdout)
        row |= {
            "perceive_inlier_index": d["inlier_index"],
            "perceive_f1": d["support_f1"],
            "perceive_unowned_depth": d["unowned_depth_fraction"],
            "perceive_bodies_merged": d["bodies_merged"],
        }
    else:
        row["errors"].append(f"perceive: {_last_line(p.stderr)}")
    episode = out / "episodes" / f"scene_{seed}"
    e = _avs(
        ["explore", "--scene", str(path), "--strategy", "utility", "--fusion", "sg",
         "--views", str(views), "--noise", noise, "--registration", registration or noise,
         "--out", str(episode)],
        1800,
    )  # fmt: skip
    metrics = episode / "metrics.json"
    if e.returncode == 0 and metrics.exists():
        m = json.loads(metrics.read_text())
        v = m["views"]
        row |= {
            "views": len(v),
            "terminated_by": m["terminated_by"],
            "f1_view1": v[0]["support_f1"] if v else 0.0,
            "f1_final": v[-1]["support_f1"] if v else 0.0,
            "precision_final": v[-1]["support_precision"] if v else 0.0,
            "recall_final": v[-1]["support_recall"] if v else 0.0,
            "inlier_index": v[-1]["inlier_index"] if v else 0.0,
            # the camera pose the map used at the last view against the truth, and how many
            # views after the first registration accepted
            "pose_error_mm": 1e3 * v[-1]["pose_error_m"] if v else 0.0,
            "registered": sum(x["registration"] == "accepted" for x in v[1:]),
            "false_positives": [e for e in m["final_support_edges"] if "#" in "".join(e)],
        }
    else:
        row["errors"].append(f"explore: {_last_line(e.stderr)}")
    row["crashed"] = bool(row["errors"])
    row["seconds"] = round(time.perf_counter() - t0, 1)
    return row


def summary(rows: list[dict]) -> dict:
    f1_final = np.array([r.get("f1_final", 0.0) if not r["crashed"] else 0.0 for r in rows])
    f1_view1 = np.array([r.get("f1_view1", 0.0) if not r["crashed"] else 0.0 for r in rows])
    inlier = np.array([r.get("inlier_index", 0.0) if not r["crashed"] else 0.0 for r in rows])
    pose = np.array([r.get("pose_error_mm", 0.0) for r in rows if not r["crashed"]] or [0.0])
    return {
        "scenes": len(rows),
        "crashed": sum(r["crashed"] for r in rows),
        "ended_at_view1": sum(r.get("views", 0) <= 1 for r in rows),
        "f1_view1_mean": float(f1_view1.mean()) if len(rows) else 0.0,
        "f1_final_mean": float(f1_final.mean()) if len(rows) else 0.0,
        "f1_final_p10": float(np.percentile(f1_final, 10)) if len(rows) else 0.0,
        "inlier_index_mean": float(inlier.mean()) if len(rows) else 0.0,
        "pose_error_mm_median": float(np.median(pose)),
        "pose_error_mm_max": float(pose.max()),
    }


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    seeds = [str(r["seed"]) for r in rows]
    x = np.arange(len(rows))
    fig, ax = plt.subplots(figsize=(max(6, 0.3 * len(rows) + 2), 3.5))
    ax.bar(x - 0.2, [r.get("f1_view1", 0) for r in rows], 0.4, label="support F1, first view")
    ax.bar(x + 0.2, [r.get("f1_final", 0) for r in rows], 0.4, label="support F1, final")
    ax.plot(x, [r.get("inlier_index", 0) for r in rows], "k.", label="InlierIndex, final")
    ax.set_xticks(x, seeds, rotation=90, fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_xlabel("scene seed")
    ax.legend(loc="lower left", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def row_text(r: dict) -> str:
    if r["crashed"]:
        return f"{r['seed']:>5}  CRASHED  {'; '.join(r['errors'])}"
    away = "away" if r["facing_away"] else "    "
    return (
        f"{r['seed']:>5} {r['objects']:>3} {away} {r.get('perceive_inlier_index', 0):6.2f} "
        f"{r['views']:>3} {r['terminated_by']:<13} {r['f1_view1']:5.2f} {r['f1_final']:5.2f} "
        f"{r['precision_final']:5.2f} {r['recall_final']:5.2f} {r['inlier_index']:5.2f} "
        f"{r['pose_error_mm']:6.1f} {r['registered']:>3}"
    )


def markdown(rows: list[dict]) -> str:
    """The README's table of a run."""

    def arrangements(r: dict) -> str:
        kinds = [a.split(":")[0] for a in r["arrangements"]]
        counts = {k: kinds.count(k) for k in dict.fromkeys(kinds)}
        return ", ".join(f"{n}× {k}" if n > 1 else k for k, n in counts.items())

    lines = [
        "| seed | objects | arrangements | start | views | F1 view 1 | F1 final | precision "
        "| recall | InlierIndex | pose error | registered |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        start = "away" if r["facing_away"] else "facing"
        if r["crashed"]:
            lines.append(f"| {r['seed']} | {r['objects']} | {arrangements(r)} | {start} | "
                         "crashed | | | | | | | |")  # fmt: skip
            continue
        lines.append(
            f"| {r['seed']} | {r['objects']} | {arrangements(r)} | {start} | {r['views']} | "
            f"{r['f1_view1']:.2f} | {r['f1_final']:.2f} | {r['precision_final']:.2f} | "
            f"{r['recall_final']:.2f} | {r['inlier_index']:.2f} | "
            + (f"{r['pose_error_mm']:.0f} mm | {r['registered']}/{r['views'] - 1} |"
               if "pose_error_mm" in r else "— | — |")
        )  # fmt: skip
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", type=int, default=30)
    parser.add_argument(
        "--first-seed", "--seed-base", dest="first_seed", type=int, default=1000,
        help="the first generated scene's seed; the scenes are this and the next --scenes - 1 "
        "(--seed-base 5000: a second subset, disjoint from the default's 1000-1029)",
    )  # fmt: skip
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument(
        "--noise", choices=["on", "off"], default="on",
        help="the robot's sensor models (depth noise included) and view registration in the "
        "episodes, as avs explore has them by default; off: the simulator's truth",
    )  # fmt: skip
    parser.add_argument(
        "--registration", choices=["on", "off"], default=None,
        help="the scene memory's view registration (default: as --noise)",
    )  # fmt: skip
    parser.add_argument("--out", type=Path, default=ROOT / "runs" / "generalization")
    parser.add_argument(
        "--markdown", type=Path, metavar="JSON",
        help="print the table of an earlier run's generalization.json and stop",
    )  # fmt: skip
    args = parser.parse_args()
    if args.markdown:
        print(markdown(json.loads(args.markdown.read_text())["rows"]))
        return
    args.out.mkdir(parents=True, exist_ok=True)
    print(" seed obj      perc.II  n  terminated    F1(1) F1(n) prec. rec.  II(n)  pose  reg",
          flush=True)  # fmt: skip
    rows = []
    for i, seed in enumerate(range(args.first_seed, args.first_seed + args.scenes)):
        rows.append(run_scene(seed, args.out, args.views, args.noise, args.registration))
        print(row_text(rows[-1]), f"  [{i + 1}/{args.scenes}, {rows[-1]['seconds']} s]", flush=True)
        (args.out / "generalization.json").write_text(
            json.dumps({"rows": rows, "summary": summary(rows)}, indent=2)
        )
    plot(rows, args.out / "generalization.png")
    s = summary(rows)
    print(f"wrote {args.out / 'generalization.json'} and {args.out / 'generalization.png'}")
    print(" ".join(f"{k}={v:.3f}" if isinstance(v, float) else f"{k}={v}" for k, v in s.items()))


if __name__ == "__main__":
    main()
