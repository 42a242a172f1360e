"""An in-process Zenoh router: what ``avs up`` runs instead of a separate zenohd."""

from __future__ import annotations

import json

import zenoh

from services.common.transport import tune

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"


class RouterError(RuntimeError):
    pass


def open_router(listen: list[str], config_file: str | None = None) -> zenoh.Session:
    """A session in router mode listening on ``listen``, multicast scouting off."""
    config = zenoh.Config.from_file(config_file) if config_file else tune(zenoh.Config())
    config.insert_json5("mode", '"router"')
    config.insert_json5("listen/endpoints", json.dumps(listen))
    config.insert_json5("scouting/multicast/enabled", "false")
    try:
        return zenoh.open(config)
    except zenoh.ZError as e:
        raise RouterError(f"cannot start the Zenoh router on {', '.join(listen)}: {e}") from None
