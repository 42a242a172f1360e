"""``avs run``: the main job — one whole exploration episode with every service as a process.

Until the services of the episode (sim, perception, scene_memory, nbv) exist, it starts what
exists, reports it and exits 0.
"""

from __future__ import annotations

import argparse
import json
import logging

from avs.commands.up import add_system_arguments, chosen_services, service_env
from avs.launcher import Supervisor
from avs.router import RouterError
from avs.services import SERVICES

log = logging.getLogger("avs.run")

EPISODE_SERVICES = ("sim", "perception", "scene_memory", "nbv")


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser(
        "run",
        help="the main job: a whole exploration episode",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_system_arguments(parser)
    parser.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    services = chosen_services(args.services)
    names = [s.name for s in services]
    missing = [n for n in EPISODE_SERVICES if n not in names]
    supervisor = Supervisor(services, args.listen, args.robot, env=service_env(args), restart=False)
    try:
        supervisor.start()
    except RouterError as e:
        raise SystemExit(f"avs: {e}") from None
    try:
        ready = supervisor.wait_ready(args.ready_timeout) if services else True
        report = {
            "router": args.listen,
            "services": supervisor.report(),
            "not_implemented": [s.name for s in SERVICES if not s.exists()],
            "episode": "needs " + ", ".join(missing) if missing else "ready",
        }
    finally:
        supervisor.stop()
    print(json.dumps(report, indent=2))
    if missing:
        log.info(
            "the exploration episode needs %s; started and stopped what exists",
            ", ".join(missing),
        )
    return 0 if ready else 1
