"""Child process of the signal test: a node (a client of AVS_CONNECT) with a periodic loop and
an input, run as every service's ``__main__`` runs it; prints "up" once it spins, then the
interpreter's switch interval in ms."""

from __future__ import annotations

import sys
from typing import ClassVar

from schemas import ImuSample, Keys
from services.common import ServiceSettings
from services.common.main import run_node


class IdleSettings(ServiceSettings):
    SERVICE: ClassVar[str] = "idle"


def build(node) -> None:
    node.subscribe(Keys().imu(), ImuSample, lambda _sample: None)
    node.every(0.01, lambda: None, "tick")
    print("up", flush=True)
    print(sys.getswitchinterval() * 1e3, flush=True)


if __name__ == "__main__":
    raise SystemExit(run_node(IdleSettings.from_args([]), build))
