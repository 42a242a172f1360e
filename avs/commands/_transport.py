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
    """ServiceSettings from the flags and AVS_* variables: a client of ``--connect`` (default
    the local ``avs up`` router) unless a mode or a Zenoh config is given."""
    overrides: dict = {}
    probe = TransportSettings.from_namespace(args)
    if probe.mode is None and probe.zenoh_config is None:
        # a command joins a running system: as a client of the router (given, or avs up's),
        # so that a wrong address fails at once instead of finding nothing as a lone peer
        overrides = {"mode": "client"}
        if not probe.connect:
            overrides["connect"] = [DEFAULT_ENDPOINT]
        if probe.multicast is None:
            overrides["multicast"] = False
    if instance:
        overrides["instance"] = instance
    try:
        return ServiceSettings.from_namespace(args, **overrides)
    except SettingsError as e:
        raise SystemExit(f"avs: {e}") from None


def connect(settings: ServiceSettings):
    """Open the session, or exit with one line naming the endpoint and why (nothing listening,
    credentials refused) — Zenoh says so within a few seconds."""
    import zenoh

    from services.common.transport import open_session

    try:
        return open_session(settings)
    except (zenoh.ZError, ValueError) as e:
        where = ", ".join(settings.connect) or "the network (peer mode)"
        user = f" as {settings.user!r}" if settings.user else ""
        reason = str(e).split(" at /", 1)[0].strip()  # Zenoh appends its source location
        raise SystemExit(f"avs: cannot connect to {where}{user}: {reason}") from None
