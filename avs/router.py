"""An in-process Zenoh router: what ``avs up`` runs instead of a separate zenohd, and the router
image's entry point: ``python -m avs.router -c CONFIG [-l ENDPOINT]...``, the arguments of
eclipse/zenoh's zenohd, so compose runs either image with the same command and config files."""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading

import zenoh

from services.common.transport import tune

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterError(RuntimeError):
    pass


def open_router(listen: list[str], config_file: str | None = None) -> zenoh.Session:
    """A session in router mode listening on ``listen`` (empty: the config file's endpoints),
    multicast scouting off."""
    config = zenoh.Config.from_file(config_file) if config_file else tune(zenoh.Config())
    config.insert_json5("mode", '"router"')
    if listen or not config_file:
        config.insert_json5("listen/endpoints", json.dumps(listen))
    else:
        listen = json.loads(config.get_json("listen/endpoints"))
    config.insert_json5("scouting/multicast/enabled", "false")
    try:
        return zenoh.open(config)
    except zenoh.ZError as e:
        raise RouterError(f"cannot start the Zenoh router on {', '.join(listen)}: {e}") from None


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("-c", "--config", help="a Zenoh JSON5 config (deploy/zenoh/router-*.json5)")
    p.add_argument(
        "-l", "--listen", action="append", default=[], help="listen here, not the config's"
    )
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s router %(message)s")
    listen = args.listen or ([] if args.config else [DEFAULT_ENDPOINT])
    try:
        session = open_router(listen, args.config)
    except RouterError as e:
        logging.error("%s", e)
        return 1
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):  # as PID 1 a signal without a handler is lost
        signal.signal(sig, lambda *_: stop.set())
    logging.info("Zenoh router %s up (config %s)", session.zid(), args.config or "default")
    stop.wait()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
