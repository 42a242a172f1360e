"""Child process of the shutdown test: a node (a client of AVS_CONNECT) whose queued input's
handler takes a second and then writes to a file that the service's ``close()`` closes, as the
scene memory journals what it fuses. Prints "up" once it spins, "handling" when a message's
handler begins and "handled" when it wrote; the handler's drops are on stderr."""

from __future__ import annotations

import sys
import tempfile
import time
from typing import ClassVar

from schemas import ImuSample, Keys
from services.common import ServiceSettings
from services.common.main import run_node


class BusySettings(ServiceSettings):
    SERVICE: ClassVar[str] = "busy"


class Busy:
    def __init__(self, node) -> None:
        self.journal = tempfile.TemporaryFile()  # noqa: SIM115 - closed in close()
        node.subscribe(Keys().imu(), ImuSample, self.on_sample, queue=4)
        print("up", flush=True)

    def on_sample(self, sample: ImuSample) -> None:
        print("handling", flush=True)
        time.sleep(1.0)
        self.journal.write(b"%d\n" % sample.seq)  # ValueError once the file is closed
        print("handled", flush=True)

    def close(self) -> None:
        self.journal.close()


if __name__ == "__main__":
    sys.exit(run_node(BusySettings.from_args([]), Busy))
