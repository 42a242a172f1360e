"""``avs gaze-experiment``: thesis 5.4.1 in the sim: the foveal camera while the hip swings,
with the gaze stabiliser on or off (``--compare``: both, printed as thesis Table 5.1), the
camera's exposure fixed or automatic (``--exposure fixed,auto``: each, and the localisation
success of every combination as in thesis Fig. 5.9b). Writes ``DIR/metrics.json``,
``flow.png`` (optical-flow error over time), ``blur.png`` and ``brightness.png``."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

from avs.commands._args import ROBOT_HELP, ROBOTS


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "gaze-experiment",
        help="object localisation while moving, stabilised or not (thesis 5.4.1, Table 5.1)",
        description=__doc__,
    )
    p.add_argument("--robot", default="armar3", choices=ROBOTS, help=ROBOT_HELP)
    p.add_argument("--scene", default="localization", help="scene name or MJCF file")
    p.add_argument("--disturbance", default="hip_yaw", help="the joint that swings")
    p.add_argument("--amplitude", type=float, default=20.0, help="A of q̇ = A·cos(2πft), deg/s")
    p.add_argument("--frequency", type=float, default=0.25, help="f, Hz")
    p.add_argument("--duration", type=float, default=10.0, help="s")
    p.add_argument(
        "--stabilize", choices=["on", "off"], default="on",
        help="the gaze stabiliser holds the fixation point (thesis 5.3) or the head stays put",
    )  # fmt: skip
    p.add_argument("--compare", action="store_true", help="run off and on, print Table 5.1")
    p.add_argument(
        "--noise", choices=["on", "off"], default="on",
        help="the robot's sensor models: gyro noise and bias, encoder noise and quantisation, "
        "joint-state latency (off: the simulator's exact state every step)",
    )  # fmt: skip
    p.add_argument(
        "--exposure", type=exposure_modes, default="fixed", metavar="fixed|auto|fixed,auto",
        help="the camera's exposure gain (thesis Fig. 5.9b): fixed where the still view set it, "
        "or the camera's auto-exposure loop (time constant 0.4 s); several: each in DIR/<mode>/ "
        "and the localisation success of every combination. Not the integration time (20 ms)",
    )  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="the sensor models' random stream")
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.set_defaults(func=_run)


def exposure_modes(text: str) -> list[str]:
    """``fixed``, ``auto`` or both, comma-separated, each once."""
    modes = [m.strip() for m in text.split(",")]
    if not all(m in ("fixed", "auto") for m in modes) or len(set(modes)) != len(modes):
        raise argparse.ArgumentTypeError(f"fixed, auto or fixed,auto, not {text!r}")
    return modes


def _bar(label: str):
    shown = [-1]

    def show(done: float) -> None:
        if int(30 * done) == shown[0]:
            return
        shown[0] = int(30 * done)
        print(f"\r{label} [{'#' * shown[0]:<30}] {100 * done:3.0f} %", end="",
              file=sys.stderr, flush=True)  # fmt: skip

    return show


def experiment(config, out: Path) -> dict:
    from experiments.gaze import run_object, summarise
    from experiments.report import gaze_plots

    out.mkdir(parents=True, exist_ok=True)
    mode = "stabilised" if config.stabilize else "unstabilised"
    runs = {}
    for name in ("cup", "textured"):
        label = f"{mode:>12} {config.exposure_mode:<5} {name:<8}"
        runs[name] = run_object(config, name, _bar(label))
        print(file=sys.stderr)
    metrics = summarise(runs) | {"config": asdict(config)}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    gaze_plots({mode: runs}, out)
    return metrics | {"runs": runs}


def table(off: dict, on: dict) -> str:
    """Thesis Table 5.1's layout: the flow error unstabilised, stabilised and the decrease;
    then localisation success, and the range of the exposure's gain and the frames' brightness
    (the auto exposure's work)."""
    fo, fn = off["flow_rmse_deg_s"], on["flow_rmse_deg_s"]
    rows = [
        ("flow RMSE mean (deg/s)", fo["mean"], fn["mean"]),
        ("flow RMSE std (deg/s)", fo["std"], fn["std"]),
        ("flow RMSE max (deg/s)", fo["max"], fn["max"]),
        ("blur mean (Crete)", off["blur"]["mean"], on["blur"]["mean"]),
    ]
    lines = [f"{'':<24}{'unstabilised':>14}{'stabilised':>12}{'decrease':>10}"]
    for name, a, b in rows:
        lines.append(f"{name:<24}{a:>14.3f}{b:>12.3f}{100 * (a - b) / a:>9.0f} %")
    for k in ("cup", "textured"):
        a, b = off["localization_success"][k], on["localization_success"][k]
        lines.append(f"{'localised: ' + k:<24}{100 * a:>13.0f}%{100 * b:>11.0f}%")
    for name, key, f in (("exposure gain", "exposure_gain", ".2f"),
                         ("frame brightness (luma)", "brightness", ".0f")):  # fmt: skip
        a, b = (f"{m[key]['min']:{f}}-{m[key]['max']:{f}}" for m in (off, on))
        lines.append(f"{name:<24}{a:>14}{b:>12}")
    return "\n".join(lines)


def success_table(summaries: dict[str, dict]) -> str:
    """Thesis Fig. 5.9b as a table: localisation success per object and exposure mode,
    unstabilised and stabilised (``summaries``: a --compare summary per exposure mode)."""
    lines = [f"{'localised':<26}{'unstabilised':>14}{'stabilised':>12}"]
    for obj in ("cup", "textured"):
        for mode, m in summaries.items():
            a, b = (m[k]["localization_success"][obj] for k in ("off", "on"))
            lines.append(f"{obj + ', ' + mode + ' exposure':<26}{100 * a:>13.0f}%{100 * b:>11.0f}%")
    return "\n".join(lines)


def _run(args: argparse.Namespace) -> int:
    from experiments.gaze import GazeExperimentConfig
    from experiments.report import gaze_plots

    def config(on: bool, exposure: str) -> GazeExperimentConfig:
        return GazeExperimentConfig(
            robot=args.robot, scene=args.scene, disturbance=args.disturbance,
            amplitude=args.amplitude, frequency=args.frequency, duration=args.duration,
            stabilize=on, exposure_mode=exposure, sensors=args.noise == "on", seed=args.seed,
        )  # fmt: skip

    results = {}
    for exposure in args.exposure:
        out = args.out if len(args.exposure) == 1 else args.out / exposure
        if not args.compare:
            m = experiment(config(args.stabilize == "on", exposure), out)
            f, found = m["flow_rmse_deg_s"], m["localization_success"]
            print(f"{exposure} exposure: flow RMSE {f['mean']:.3f} ± {f['std']:.3f} deg/s (max "
                  f"{f['max']:.3f}), blur {m['blur']['mean']:.3f}, localised: cup "
                  f"{found['cup']:.0%}, textured {found['textured']:.0%}")  # fmt: skip
            results[exposure] = {k: v for k, v in m.items() if k != "runs"}
            continue
        off = experiment(config(False, exposure), out / "off")
        on = experiment(config(True, exposure), out / "on")
        summary = {
            k: {m: v for m, v in r.items() if m != "runs"} for k, r in (("off", off), ("on", on))
        }
        summary["flow_decrease"] = (
            1 - on["flow_rmse_deg_s"]["mean"] / off["flow_rmse_deg_s"]["mean"]
        )
        (out / "metrics.json").write_text(json.dumps(summary, indent=2))
        gaze_plots({"unstabilised": off["runs"], "stabilised": on["runs"]}, out)
        if len(args.exposure) > 1:
            print(f"{exposure} exposure")
        print(table(off, on))
        results[exposure] = summary
    if len(args.exposure) > 1:
        (args.out / "metrics.json").write_text(json.dumps(results, indent=2))
        if args.compare:
            print(success_table(results))
        where = ", ".join(f"{e}/" for e in args.exposure)
        print(f"wrote {args.out}/metrics.json and {where} (each: metrics.json, plots)")
    elif args.compare:
        print(f"wrote {args.out}/metrics.json (and off/, on/), flow.png, blur.png, brightness.png")
    else:
        print(f"wrote {args.out / 'metrics.json'}, flow.png, blur.png, brightness.png")
    return 0
