"""``avs up``: the Zenoh router on loopback plus every implemented service as a local process.

The services join the router's Zenoh network as peers with multicast off, linked directly to
each other over loopback (``--clients``: as clients, every message through the router, the
wiring of compose.yaml) — the same commands as compose.yaml, without docker. Ctrl-C (or
SIGTERM) stops them all. A service that exits, or hangs (its metrics unanswered for
--hung-after seconds), is restarted after a back-off that doubles with every quick failure
(0.5 s … 30 s); ``avs status`` names any that is down.
The scene memory runs with a hot standby (``--no-standby``: without), which takes over within
2 s when the active one dies; the router's threads, the sim's physics and the gaze run with
real-time scheduling where the OS permits it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import threading
from pathlib import Path

from avs.commands._args import positive_float
from avs.launcher import HUNG_AFTER_S, Supervisor
from avs.router import DEFAULT_ENDPOINT, RouterError
from avs.services import BY_NAME, SERVICES, ServiceInfo, existing

log = logging.getLogger("avs.up")

#: frames perception takes a second in the live stack (the newest each time; compose.yaml
#: sets the same): the semantic path (perception ~45 ms of CPU a frame, the fusion of its
#: observation ~30 ms) takes a third of a core at this rate, at a higher priority than the
#: map, which takes what is left of the core that rendering, physics and the 1 kHz gaze loop
#: leave on 2 cores (benchmarks/pipeline.py: ≥ 5 semantic frames a second on the kitchen);
#: uncapped, perception took 11 a second, which the fusion could not keep up with, and the
#: semantic model fell seconds behind
LIVE_PERCEPTION_RATE = 6.0
#: with the sensor models on, each view registration is weighed against the odometry's error,
#: 2 % of the camera's motion (the sim's platform drifts 1.5 % of the distance;
#: services/scene_memory/correction_filter.py): taken as they come, registrations of frames
#: that barely overlap the map while the platform drives around the table were accepted 2.5°
#: off in yaw (the odometry was 0.25° off), and the map kept the error
LIVE_ODOMETRY_NOISE = 0.02
#: the sim's scene when ``--scene`` is not given (services/sim/config.py's default)
DEFAULT_SCENE = "tabletop_occluded"


def add_system_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--listen",
        default=DEFAULT_ENDPOINT,
        help=f"the router's endpoint (default {DEFAULT_ENDPOINT})",
    )
    parser.add_argument("--robot", default="armar6", help="robot name (default armar6)")
    parser.add_argument(
        "--services",
        default="",
        help="comma-separated services to start (default: every implemented one of "
        + ", ".join(s.name for s in SERVICES)
        + ")",
    )
    parser.add_argument(
        "--data-dir",
        type=Path,
        default=Path("avs-data"),
        help="where stateful services keep their data, one directory each (default avs-data)",
    )
    parser.add_argument(
        "--ready-timeout",
        type=float,
        default=60.0,
        help="seconds to wait for every service's liveliness token (default 60)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "up",
        help="start the router and every service as local processes",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_system_arguments(parser)
    parser.add_argument(
        "--no-restart", action="store_true", help="do not restart a service that exits"
    )
    parser.add_argument(
        "--no-standby",
        action="store_true",
        help="run one scene memory, without the hot standby that serves within 2 s of a crash",
    )
    parser.add_argument(
        "--hung-after",
        type=positive_float,
        default=HUNG_AFTER_S,
        metavar="S",
        help=f"restart a service silent this long (default {HUNG_AFTER_S:.0f} s)",
    )
    parser.add_argument(
        "--scene", default=None, metavar="S",
        help="the sim's scene: a built-in name or an MJCF file (default: the sim's, "
        "tabletop_occluded; overrides AVS_SIM_SCENE)",
    )  # fmt: skip
    parser.add_argument(
        "--explore", action="store_true",
        help="explore by itself: the explorer starts an episode in the scene's roi once the "
        "services are up (the planner and scene memory get the scene's roi, view-sphere "
        "centres and map bounds); explore/status says what it does",
    )  # fmt: skip
    parser.add_argument(
        "--views", type=int, default=10, metavar="N",
        help="with --explore: views an episode takes at most (default 10)",
    )  # fmt: skip
    parser.add_argument(
        "--noise", choices=["on", "off"], default="on",
        help="the sim's sensor models (depth noise, gyro, encoders, latency, odometry drift) "
        "and the scene memory's view registration, or the simulator's truth (AVS_SIM_NOISE, "
        "AVS_SIM_SENSORS and AVS_SCENE_MEMORY_REGISTRATION, when set, win)",
    )  # fmt: skip
    parser.add_argument(
        "--clients", action="store_true",
        help="services connect as Zenoh clients, every message through the router (the "
        "default: as peers, linked directly to each other on loopback)",
    )  # fmt: skip
    parser.add_argument(
        "--scale",
        type=parse_scale,
        default={},
        metavar="NAME=N,…",
        help="instances of scalable services, e.g. perception=3,nbv=2",
    )
    parser.set_defaults(func=_up)


def parse_scale(text: str) -> dict[str, int]:
    scale = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        name, _, n = part.partition("=")
        if not n.isdigit() or int(n) < 1:
            raise argparse.ArgumentTypeError(f"{part!r}: expected NAME=N with N ≥ 1")
        scale[name.strip()] = int(n)
    return scale


def service_env(args: argparse.Namespace) -> dict[str, str]:
    """Settings the launcher hands to the services: the scene memory's data directory, and the
    sensor models with view registration weighed against the odometry (``--noise``) and
    perception's rate unless the environment says otherwise."""
    on = str(getattr(args, "noise", "on") == "on").lower()
    keys = ("AVS_SIM_NOISE", "AVS_SIM_SENSORS", "AVS_SCENE_MEMORY_REGISTRATION")
    noise = {k: on for k in keys if k not in os.environ}
    if on == "true" and "AVS_SCENE_MEMORY_ODOMETRY_NOISE" not in os.environ:
        noise["AVS_SCENE_MEMORY_ODOMETRY_NOISE"] = f"{LIVE_ODOMETRY_NOISE:g}"
    # perception at most LIVE_PERCEPTION_RATE frames a second (AVS_PERCEPTION_MAX_RATE=0 in the
    # environment: every frame)
    rate = (
        {}
        if "AVS_PERCEPTION_MAX_RATE" in os.environ
        else {"AVS_PERCEPTION_MAX_RATE": f"{LIVE_PERCEPTION_RATE:g}"}
    )
    scene = {"AVS_SIM_SCENE": args.scene} if getattr(args, "scene", None) else {}
    explore = {}
    if getattr(args, "explore", False):
        chosen = args.scene or os.environ.get("AVS_SIM_SCENE") or DEFAULT_SCENE
        explore = explore_env(chosen, args.robot, args.views)
    return (
        noise
        | rate
        | scene
        | explore
        | {"AVS_SCENE_MEMORY_DATA_DIR": str(Path(args.data_dir) / "scene_memory")}
    )


def explore_env(scene: str, robot: str, views: int) -> dict[str, str]:
    """What the services need to know of the scene to explore it on their own (the settings
    ``avs explore`` hands them too): the roi whose unknown voxels count, the view spheres'
    centres, where the platform may go, the map's bounds; the explorer starts by itself."""
    import numpy as np

    from experiments.episode import scene_facts

    try:
        facts = scene_facts(scene, robot)
    except Exception as e:  # a wrong scene file names its problem
        raise SystemExit(f"avs: --explore: the scene {scene!r}: {e}") from None
    csv = lambda v: ",".join(f"{x:.4f}" for x in np.ravel(v))  # noqa: E731
    roi = {"MIN": csv(facts.roi_min), "MAX": csv(facts.roi_max)}
    env = {
        "AVS_EXPLORER_AUTOSTART": "true",
        "AVS_EXPLORER_VIEWS": str(views),
        "AVS_NBV_CENTRE": csv(facts.centres),
        "AVS_NBV_FIRST_TARGET": csv(facts.centre),
        # the explorer counts the views (a goal abandoned takes a step and no view)
        "AVS_NBV_MAX_VIEWS": "1000",
        "AVS_SCENE_MEMORY_BOUNDS_MIN": csv(facts.map_min),
        "AVS_SCENE_MEMORY_BOUNDS_MAX": csv(facts.map_max),
    }
    for side, value in roi.items():
        for service in ("EXPLORER", "NBV", "SCENE_MEMORY"):
            env[f"AVS_{service}_ROI_{side}"] = value
    if facts.workspace is not None:
        env["AVS_NBV_WORKSPACE_MIN"] = csv(facts.workspace[0][:2])
        env["AVS_NBV_WORKSPACE_MAX"] = csv(facts.workspace[1][:2])
    return {k: v for k, v in env.items() if k not in os.environ}


def data_dir_note(data_dir: Path) -> str:
    """Where the stateful services keep their state, and what a restart does with it."""
    memory = data_dir / "scene_memory"
    held = memory.is_dir() and any(memory.iterdir())
    return (
        f"the scene memory keeps its state in {memory.resolve()} "
        + ("(there is one: it restores it; delete the folder to start empty)" if held
           else "(empty: it starts empty; a restart restores from it)")
        + " (--data-dir)"
    )  # fmt: skip


def chosen_services(names: str) -> list[ServiceInfo]:
    if not names:
        return existing()
    chosen = []
    for name in (n.strip() for n in names.split(",") if n.strip()):
        info = BY_NAME.get(name)
        if info is None:
            raise SystemExit(f"avs: unknown service {name!r} (known: {', '.join(BY_NAME)})")
        if not info.exists():
            raise SystemExit(f"avs: service {name!r} is not implemented yet")
        chosen.append(info)
    return chosen


def _up(args: argparse.Namespace) -> int:
    services = chosen_services(args.services)
    scale = dict(args.scale)
    if not args.no_standby and any(s.name == "scene_memory" for s in services):
        scale.setdefault("scene_memory", 2)  # one active, one standing by to take over
    try:
        supervisor = Supervisor(
            services, args.listen, args.robot, env=service_env(args),
            restart=not args.no_restart, scale=scale, hung_after=args.hung_after,
            realtime=True, peers=not args.clients,
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(f"avs: {e}") from None
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        supervisor.start()
    except RouterError as e:
        raise SystemExit(f"avs: {e}") from None
    if any(s.name == "scene_memory" for s in services):
        log.info(data_dir_note(Path(args.data_dir)))
    try:
        missing = [s.name for s in SERVICES if s not in services]
        if missing:
            log.info("not started (not implemented or not chosen): %s", ", ".join(missing))
        if services and supervisor.wait_ready(args.ready_timeout):
            log.info("all services alive: %s", ", ".join(s.name for s in services))
        elif services:
            log.warning("not every service is alive: %s", json.dumps(supervisor.report()))
        log.info("ready; Ctrl-C stops everything")
        print(json.dumps({"router": args.listen, "services": supervisor.report()}), flush=True)
        supervisor.run_until(stop)
    finally:
        supervisor.stop()
    return 0
