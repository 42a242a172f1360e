"""The small runtime every service shares: settings, Zenoh sessions, the node shell, metrics,
logging. Services import this and ``schemas``, never each other."""

from services.common.config import ServiceSettings, Settings, SettingsError, TransportSettings
from services.common.log import setup_logging
from services.common.metrics import Metrics
from services.common.node import Node, Output, RemoteError
from services.common.transport import open_session, zenoh_config

__all__ = [
    "Metrics",
    "Node",
    "Output",
    "RemoteError",
    "ServiceSettings",
    "Settings",
    "SettingsError",
    "TransportSettings",
    "open_session",
    "setup_logging",
    "zenoh_config",
]
