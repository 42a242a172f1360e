"""The ``__main__`` of every service: settings → logging → node → the service → spin → close."""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from typing import Any

from services.common.config import ServiceSettings
from services.common.log import setup_logging
from services.common.node import Node


def run_node(settings: ServiceSettings, build: Callable[[Node], Any]) -> int:
    """Start a node for ``settings`` (the interpreter's switch interval set first), let
    ``build(node)`` declare the service's inputs and outputs, and block until SIGINT/SIGTERM
    (or the service stops the node). Whatever ``build`` returns is closed (if it has
    ``close()``) once the node's inputs are stopped and their handlers finished
    (``Node.stop_inputs``), and before its outputs and session go."""
    service = type(settings).SERVICE
    sys.setswitchinterval(settings.switch_interval_ms / 1e3)
    setup_logging(service, settings.instance, settings.log_level, settings.log_format)
    log = logging.getLogger(f"avs.{service}")
    log.debug("settings", extra={"settings": settings.model_dump(mode="json")})
    with Node(service, settings, announce=False) as node:
        node.install_signal_handlers()
        worker = build(node)
        node.announce()
        try:
            node.spin()
        finally:
            node.stop_inputs()
            close = getattr(worker, "close", None)
            if callable(close):
                close()
    return 0
