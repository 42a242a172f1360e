"""Transport flags shared by the commands that join a running system (echo, record …)."""

from __future__ import annotations

import argparse

from avs.router import DEFAULT_ENDPOINT
from services.common.config import ServiceSettings, SettingsError, TransportSettings


def add_transport_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group(
        "transport",
        f"how to reach the system (default: client of {DEFAULT_ENDPOINT}, as started by 'avs up')",
    )
    TransportSettings.add_arguments(group)  # type: ignore[arg-type]


def settings_from(args: argparse.Namespace, instance: str | None = None) -> ServiceSettings:
    """ServiceSettings from the flags and AVS_* variables; without any transport choice the
    command connects as a client to the local ``avs up`` router."""
    overrides: dict = {}
    probe = TransportSettings.from_namespace(args)
    if probe.mode is None and not probe.connect and probe.zenoh_config is None:
        overrides = {"mode": "client", "connect": [DEFAULT_ENDPOINT]}
        if probe.multicast is None:
            overrides["multicast"] = False
    if instance:
        overrides["instance"] = instance
    try:
        return ServiceSettings.from_namespace(args, **overrides)
    except SettingsError as e:
        raise SystemExit(f"avs: {e}") from None
