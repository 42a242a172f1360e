"""Opening Zenoh sessions from settings, and the QoS of each key."""

from __future__ import annotations

import json

import zenoh

from schemas.keys import spec_for
from services.common.config import TransportSettings

_PRIORITY = {
    "real_time": zenoh.Priority.REAL_TIME,
    "interactive_high": zenoh.Priority.INTERACTIVE_HIGH,
    "interactive_low": zenoh.Priority.INTERACTIVE_LOW,
    "data_high": zenoh.Priority.DATA_HIGH,
    "data": zenoh.Priority.DATA,
    "data_low": zenoh.Priority.DATA_LOW,
}
_CONGESTION = {"drop": zenoh.CongestionControl.DROP, "block": zenoh.CongestionControl.BLOCK}
#: publisher options over the key table's: every message is put, none dropped on congestion (a
#: slow subscriber holds the publisher back): the sim's state streams in lockstep, a replay
LOSSLESS = {"congestion_control": zenoh.CongestionControl.BLOCK}


#: Transmission queues (in 64 KB batches, at most 16) per priority. With Zenoh's default of 2, a
#: 2 MB camera frame on the same link crowds out a 1 kHz real-time stream (IMU, joint states)
#: long enough to drop samples: 2-22 % of 1,000 IMU samples on a loaded 2-core machine, none
#: with these depths (tests/test_transport.py).
TX_QUEUE_SIZES = {"real_time": 16, "interactive_high": 16, "interactive_low": 4, "data": 4}
#: How long a drop-on-congestion message may wait for queue space (µs; Zenoh's default 1000).
WAIT_BEFORE_DROP_US = 5000


def tune(config: zenoh.Config) -> zenoh.Config:
    """Apply AVS's transport defaults (queue depths) to a config built from scratch."""
    for priority, size in TX_QUEUE_SIZES.items():
        config.insert_json5(f"transport/link/tx/queue/size/{priority}", str(size))
    config.insert_json5(
        "transport/link/tx/queue/congestion_control/drop/wait_before_drop", str(WAIT_BEFORE_DROP_US)
    )
    return config


def zenoh_config(settings: TransportSettings) -> zenoh.Config:
    """A Zenoh config: the JSON5 file if given (used as is), else AVS's defaults; every
    explicitly set flag is applied on top."""
    config = (
        zenoh.Config.from_file(str(settings.zenoh_config))
        if settings.zenoh_config
        else tune(zenoh.Config())
    )
    if settings.mode is not None:
        config.insert_json5("mode", json.dumps(settings.mode))
    if settings.connect:
        config.insert_json5("connect/endpoints", json.dumps(settings.connect))
    if settings.listen:
        config.insert_json5("listen/endpoints", json.dumps(settings.listen))
    if settings.multicast is not None:
        config.insert_json5("scouting/multicast/enabled", json.dumps(settings.multicast))
    if settings.user:
        if settings.password is None:
            raise ValueError("a user needs a password (AVS_PASSWORD or --password)")
        auth = {"user": settings.user, "password": settings.password.get_secret_value()}
        config.insert_json5("transport/auth/usrpwd", json.dumps(auth))
    if settings.tls_ca is not None:
        ca = json.dumps(str(settings.tls_ca))
        config.insert_json5("transport/link/tls/root_ca_certificate", ca)
    return config


def open_session(settings: TransportSettings) -> zenoh.Session:
    return zenoh.open(zenoh_config(settings))


def publisher_options(key: str) -> dict:
    """declare_publisher keyword arguments for ``key`` from the key table (SPEC §1)."""
    spec = spec_for(key)
    if spec is None:
        return {}
    return {
        "congestion_control": _CONGESTION[spec.congestion],
        "priority": _PRIORITY[spec.priority],
        "express": spec.express,
    }
