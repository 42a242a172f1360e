"""``python -m services.common.health SERVICE``: exit 0 when this host runs a live instance of
SERVICE (a liveliness token ``alive/SERVICE/<hostname>-…``, the default instance name), 1
otherwise: the health check compose runs in each container. Transport settings as every
service's (AVS_CONNECT, AVS_USER, …)."""

from __future__ import annotations

import socket
import sys

from schemas.keys import Keys
from services.common.config import ServiceSettings
from services.common.transport import open_session


def healthy(service: str, settings: ServiceSettings, timeout: float = 3.0) -> bool:
    keys = Keys(settings.robot)
    prefix = keys.alive(service, socket.gethostname().replace("/", "-") + "-")
    with open_session(settings) as session:
        for reply in session.liveliness().get(keys.alive(service), timeout=timeout):
            if reply.ok and str(reply.ok.key_expr).startswith(prefix.rstrip("*")):
                return True
    return False


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 1:
        print("usage: python -m services.common.health SERVICE", file=sys.stderr)
        return 2
    settings = ServiceSettings.from_args([])
    ok = healthy(argv[0], settings)
    print(f"{argv[0]}: {'alive' if ok else 'no live instance on this host'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
