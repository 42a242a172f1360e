"""Real-time scheduling for the loops whose rate is sacred (the gaze's 1 kHz control, the
sim's physics and IMU): ``SCHED_RR`` where the OS permits it (root, or CAP_SYS_NICE in a
container), else a nice of −10, else nothing — and it says which in one log line.

Called once the process's node is up, it sets every thread there is (Zenoh's included) and,
since Linux threads inherit their creator's policy, every thread started later; a thread that
must not have it (the sim's renderer) calls ``ordinary()`` for itself. Round-robin rather
than FIFO: threads of one priority share their CPU in slices instead of one keeping it until
it blocks. (Python's GIL switch interval stays at its 5 ms: at 0.5 ms the handoffs cost more
than they won, on the soak benchmark 650-820 Hz of IMU against 910 Hz.)
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
from pathlib import Path

log = logging.getLogger("avs.realtime")

#: SCHED_RR priority (1-99): above every ordinary thread, below the kernel's own
RR_PRIORITY = 10
NICE = -10
#: the nice of the camera-rate path (perception's worker): after the real-time loops, before
#: rendering, tools and the map. A frame perceived late costs the whole pipeline its rate.
FOREGROUND = -5
#: the nice of deferrable work: it yields to perception and rendering, which yield to the
#: real-time loops. (The scene memory's map and fusion ran here until the map became part of the
#: end-to-end rate, issue 18: they run at nice 0 now.)
BACKGROUND = 10


def threads() -> list[int]:
    """The ids of this process's threads (Linux: /proc/self/task)."""
    try:
        return [int(t.name) for t in Path("/proc/self/task").iterdir()]
    except OSError:
        return [0]


def prioritise(what: str, main_thread: bool = True) -> str:
    """Real-time scheduling for every thread of this process (and those it starts later);
    returns what was granted: "SCHED_RR", "nice -10" or "none". ``main_thread=False`` leaves
    the main thread (and what it starts or forks from now on) ordinary: ``avs up`` gives its
    router's threads priority, not the services it spawns."""
    granted = "none"
    tids = [t for t in threads() if main_thread or t != os.getpid()]
    try:
        for tid in tids:
            os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(RR_PRIORITY))
        granted = "SCHED_RR"
    except (AttributeError, PermissionError, OSError):
        try:
            for tid in tids:
                os.setpriority(os.PRIO_PROCESS, tid, NICE)
            granted = f"nice {NICE}"
        except (AttributeError, PermissionError, OSError):
            pass
    if granted == "none":
        log.warning("%s runs without real-time scheduling: SCHED_RR and a negative nice need "
                    "root or CAP_SYS_NICE", what)  # fmt: skip
    else:
        log.info("%s runs with real-time scheduling", what, extra={"granted": granted})
    return granted


def ordinary(nice: int = 0) -> None:
    """The calling thread back to ordinary scheduling (e.g. a renderer in a real-time
    process) at ``nice``: it then competes like any other (nice 0), or after the others
    (``BACKGROUND``). Raising one's own nice needs no privilege; lowering it does, and is
    skipped where refused."""
    with contextlib.suppress(AttributeError, PermissionError, OSError):
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    with contextlib.suppress(AttributeError, PermissionError, OSError):
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), nice)


def foreground(what: str) -> bool:
    """The calling thread at ordinary scheduling and nice ``FOREGROUND`` where permitted (a
    negative nice needs root or CAP_SYS_NICE); says which in one log line."""
    ordinary(FOREGROUND)
    try:
        granted = os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == FOREGROUND
    except (AttributeError, OSError):
        granted = False
    if granted:
        log.info("%s runs at nice %d", what, FOREGROUND)
    else:
        log.warning("%s runs at nice 0: a negative nice needs root or CAP_SYS_NICE", what)
    return granted


def os_thread_name(name: str) -> None:
    """Give the calling thread ``name`` where the OS shows it (Linux: the 15 bytes of
    /proc/<pid>/task/<tid>/comm that top -H and ps -L print), so a thread's CPU can be told
    from the others' (benchmarks/soak.py's per-thread table)."""
    with contextlib.suppress(OSError, AttributeError):
        Path(f"/proc/self/task/{threading.get_native_id()}/comm").write_text(name[:15])
