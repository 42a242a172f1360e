"""The ``__main__`` of every service: settings → logging → node → the service → spin → close."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import Any, TypeVar

from services.common.config import ServiceSettings
from services.common.log import setup_logging
from services.common.node import Node

S = TypeVar("S", bound=ServiceSettings)


def run_service(
    settings_type: type[S], build: Callable[[Node, S], Any], argv: list[str] | None = None
) -> int:
    """Parse the settings, start a node, let ``build(node, settings)`` declare the service's
    inputs and outputs, and block until SIGINT/SIGTERM. Whatever ``build`` returns is closed
    (if it has ``close()``) before the node."""
    settings = settings_type.from_args(argv)
    service = settings_type.SERVICE
    setup_logging(service, settings.instance, settings.log_level, settings.log_format)
    log = logging.getLogger(f"avs.{service}")
    log.info("settings", extra={"settings": settings.model_dump(mode="json")})
    with Node(service, settings) as node:
        node.install_signal_handlers()
        worker = build(node, settings)
        try:
            node.spin()
        finally:
            close = getattr(worker, "close", None)
            if callable(close):
                close()
    return 0


def main_entry(settings_type: type[S], build: Callable[[Node, S], Any]) -> None:
    sys.exit(run_service(settings_type, build))
