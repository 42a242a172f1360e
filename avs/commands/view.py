"""``avs view``: watch a running system live in rerun, in world coordinates on one timeline —
the camera images and the frame's point cloud, perceived and fused primitives with their
support graphs, the occupancy map's occupied voxels and the roi, the next-best-view candidates
coloured by utility with the chosen view's frustum, the platform's path, the gaze target and
the ego-sphere's saliency (entity paths: ``avs/viewer.py``).

It subscribes like any outside tool (as ``observer`` against a compose deployment) and asks
the scene memory for its map every ``--map-period`` seconds when it changed. With a display it
spawns the native viewer; ``--web`` serves the web viewer (its address is printed);
``--save FILE`` writes a ``.rrd`` recording (no display needed; open it with ``rerun FILE``).
Ctrl-C (or ``--timeout``) stops it after logging what is still waiting and the map once more.
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from avs.commands._args import positive_float, positive_int
from avs.commands._transport import add_transport_arguments, connect, settings_from
from schemas import BoxQuery, OccupancySlice, OccupancyStats, SceneModel
from schemas.base import Message
from schemas.codec import CodecError, decode
from services.common.node import Node, RemoteError

if TYPE_CHECKING:  # rerun is imported when the command runs, not for 'avs --help'
    from collections.abc import Callable

    import rerun as rr
    import zenoh

    from avs.viewer import SceneLogger

log = logging.getLogger("avs.view")

#: the keys the viewer subscribes to (relative to avs/<robot>/) and the least time between two
#: logged messages of one concrete key, s (the newest waits its turn: none is lost for good)
STREAMS: dict[str, float] = {
    "sensors/rgbd/*": 0.2,
    "sensors/cloud/*": 0.2,
    "perception/observation": 0.0,
    "memory/scene": 0.0,
    "nbv/candidates": 0.0,
    "nbv/next_view": 0.0,
    "gaze/target": 0.0,
    "gaze/egosphere": 0.2,
    "state/base": 0.05,
}
#: the box asked of the scene memory for the whole map
WHOLE_MAP = BoxQuery(box_min=np.full(3, -1e3), box_max=np.full(3, 1e3))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="watch the system live in rerun (native viewer, --web, or --save FILE.rrd)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--spawn", action="store_true",
        help="spawn the native viewer (the default without --web and --save)",
    )  # fmt: skip
    p.add_argument("--web", action="store_true", help="serve the web viewer; prints its address")
    p.add_argument("--web-port", type=int, default=9090, help="web viewer port (0: any free)")
    p.add_argument(
        "--bind", default="127.0.0.1", metavar="ADDR",
        help="the address --web's viewer and data ports listen on (default 127.0.0.1: this "
        "machine only; 0.0.0.0 for every interface)",
    )  # fmt: skip
    p.add_argument("--grpc-port", type=int, default=9876, help="rerun's data port (0: any free)")
    p.add_argument(
        "--save", type=Path, metavar="FILE", help="write the recording to FILE (.rrd); headless"
    )
    p.add_argument("--timeout", type=float, default=0.0, help="stop after S seconds (0: at Ctrl-C)")
    p.add_argument(
        "--map-period", type=positive_float, default=2.0,
        help="ask for the occupancy map this often when it changed, s",
    )  # fmt: skip
    p.add_argument(
        "--map-block", type=positive_float, default=0.04,
        help="occupied voxels are shown pooled to cubes of about this side, m",
    )  # fmt: skip
    p.add_argument(
        "--cloud-stride", type=positive_int, default=4,
        help="the frame's point cloud takes every n-th pixel in each direction",
    )  # fmt: skip
    p.add_argument(
        "--instance", default=None,
        help="this viewer's name: it is alive as alive/view/<instance> while subscribed",
    )  # fmt: skip
    add_transport_arguments(p)
    p.set_defaults(func=_view)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class Viewer:
    """The subscriber side: raw samples are kept newest-per-key by the Zenoh callbacks (no
    decoding there); one worker thread decodes them in arrival order, turns them into entities
    (``avs.viewer.SceneLogger``) and logs them; a second thread asks for the map."""

    def __init__(
        self, node: Node, recording: rr.RecordingStream, logger: SceneLogger, map_period: float
    ) -> None:
        self.node = node
        self.recording = recording
        self.logger = logger
        self.map_period = map_period
        self.cond = threading.Condition()
        #: concrete key → (arrival time, payload bytes or a decoded message)
        self.pending: dict[str, tuple[float, Any]] = {}
        self.next_allowed: dict[str, float] = {}
        self.interval: dict[str, float] = {}
        self.map_wanted = threading.Event()
        self.map_version = -1
        self.logged = 0
        self.superseded = 0
        self.stopping = False
        self._subscribers: list[Any] = []
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        from avs.viewer import log_entities

        log_entities(self.recording, self.logger.setup(), time.time())
        for relative, interval in STREAMS.items():
            key = self.node.keys.key(relative)
            self._subscribers.append(
                self.node.session.declare_subscriber(key, self._on_sample(interval))
            )
        for target, name in ((self._work, "view:log"), (self._poll_map, "view:map")):
            thread = threading.Thread(target=target, name=name, daemon=True)
            thread.start()
            self._threads.append(thread)

    def _on_sample(self, interval: float) -> Callable[[zenoh.Sample], None]:
        def on_sample(sample: zenoh.Sample) -> None:  # Zenoh's thread: keep the bytes, nothing more
            key = str(sample.key_expr)
            self.node.metrics.count_in(key)
            self.put(key, sample.payload.to_bytes(), interval)

        return on_sample

    def put(self, key: str, item: Any, interval: float = 0.0) -> None:
        """Keep ``item`` as ``key``'s newest, replacing one still waiting."""
        with self.cond:
            if key in self.pending:
                self.superseded += 1  # a newer one of the same key replaced it: expected
            self.pending[key] = (time.time(), item)
            self.interval[key] = interval
            self.cond.notify()

    def _due(self, drain: bool) -> tuple[list[tuple[float, str, Any]], float | None]:
        """The waiting items whose key may be logged now, oldest first, and how long until the
        next one may (None: nothing waits)."""
        now = time.monotonic()
        due = [(t, k, v) for k, (t, v) in self.pending.items()
               if drain or self.next_allowed.get(k, 0.0) <= now]  # fmt: skip
        for _, k, _ in due:
            del self.pending[k]
            self.next_allowed[k] = now + self.interval.get(k, 0.0)
        later = [self.next_allowed.get(k, 0.0) - now for k in self.pending]
        return sorted(due, key=lambda d: d[0]), (max(0.0, min(later)) if later else None)

    def _work(self) -> None:
        while True:
            with self.cond:
                due, wait = self._due(False)
                while not due and not self.stopping:
                    self.cond.wait(wait)
                    due, wait = self._due(False)
                if not due and self.stopping:
                    return
            for stamp, key, item in due:
                self._log(stamp, key, item)

    def _log(self, stamp: float, key: str, item: Any) -> None:
        from avs.viewer import log_entities

        message = item
        if isinstance(item, bytes):
            try:
                message = decode(item, Message)
            except CodecError as e:
                self.node.drop(e.kind, key, str(e))
                return
        try:
            entities = self.logger.entities(message)
            log_entities(self.recording, entities, stamp)
        except Exception as e:  # a message the drawing cannot take never stops the viewer
            self.node.drop(f"draw_error:{type(e).__name__}", key, f"drawing it raised {e!r}")
            return
        self.logged += 1
        if isinstance(message, SceneModel):
            self.map_wanted.set()  # a new view was fused: the map changed too

    def refresh_map(self) -> None:
        """Ask for the roi's counts; when the map changed since the last time, for the whole
        map too (paged replies, joined)."""
        k = self.node.keys
        try:
            stats = self.node.query(k.occupancy("stats"), None, OccupancyStats, timeout=5)
            if not stats or stats[0].map_version == self.map_version:
                return
            pages = self.node.query(
                k.occupancy("slice"), WHOLE_MAP, OccupancySlice, timeout=30, every_reply=True
            )
            piece = OccupancySlice.join(pages)
        except (RemoteError, ValueError, TimeoutError) as e:
            log.debug("no map: %s", e)
            return
        self.map_version = piece.map_version
        self.put(k.occupancy("stats"), stats[0])
        self.put(k.occupancy("slice"), piece)

    def _poll_map(self) -> None:
        while not self.stopping:
            self.map_wanted.wait(self.map_period)
            self.map_wanted.clear()
            if self.stopping:
                return
            try:
                self.refresh_map()
            except Exception as e:  # the map is shown when it can be; the viewer goes on
                self.node.drop(f"map_error:{type(e).__name__}", "memory/occupancy", repr(e))

    def stop(self) -> None:
        """Stop listening, ask for the map once more, log everything still waiting."""
        for subscriber in self._subscribers:
            subscriber.undeclare()
        with self.cond:
            self.stopping = True
            self.cond.notify_all()
        self.map_wanted.set()
        for thread in self._threads:
            thread.join(timeout=60)
        self.refresh_map()
        with self.cond:
            due, _ = self._due(True)
        for stamp, key, item in due:
            self._log(stamp, key, item)
        self.recording.flush()


def open_recording(args: argparse.Namespace) -> tuple[rr.RecordingStream, list[str]]:
    """The rerun recording with its sinks (file, web, native viewer) and what to tell the
    user about them; SystemExit when there is nowhere to show it."""
    import rerun as rr

    recording = rr.RecordingStream("avs", make_default=False)
    sinks: list[Any] = []
    notes: list[str] = []
    if args.save:
        args.save.parent.mkdir(parents=True, exist_ok=True)
        sinks.append(rr.FileSink(str(args.save)))
        notes.append(f"recording to {args.save}")
    grpc_port = args.grpc_port or free_port()
    if args.web:
        web_port = args.web_port or free_port()
        uri = serve_web(args.bind, web_port, grpc_port)
        sinks.append(rr.GrpcSink(uri))
        host = uri.split("//", 1)[1].split(":", 1)[0]
        notes.append(f"web viewer: http://{host}:{web_port}/?url={quote(uri, safe='')}")
    if args.spawn or not (args.web or args.save):
        if not has_display():
            raise SystemExit(
                "avs view: no display (DISPLAY / WAYLAND_DISPLAY unset): use --web to serve "
                "the web viewer or --save FILE.rrd to record"
            )
        rr.spawn(port=grpc_port, connect=False, executable_path=rerun_beside())
        sinks.append(rr.GrpcSink(f"rerun+http://127.0.0.1:{grpc_port}/proxy"))
        notes.append(f"native viewer on port {grpc_port}")
    recording.set_sinks(*sinks)
    return recording, notes


def rerun_beside() -> str | None:
    """The rerun CLI of this Python's environment (the venv's, on PATH or not), if any."""
    beside = Path(sys.executable).with_name("rerun")
    return str(beside) if beside.exists() else None


def serve_web(bind: str, web_port: int, grpc_port: int, timeout: float = 30.0) -> str:
    """The rerun CLI as a process (``rerun --serve-web --bind ADDR``): the web viewer's page
    and a data proxy the recording streams to, both on ``bind`` only (the SDK's own web
    server listens on every interface, whatever it is told). It ends with this process.
    Returns the proxy's URI, as a browser on this machine (or, bound to every interface,
    elsewhere: this host's name) reaches it."""
    beside = rerun_beside()
    command = [beside] if beside else [sys.executable, "-m", "rerun"]
    # its own process group, ended whole (``_end``): the venv's ``rerun`` is a Python wrapper
    # that runs the rerun binary as its child, which outlived a terminated wrapper
    proc = subprocess.Popen(
        [*command, "--serve-web", "--bind", bind, "--port", str(grpc_port),
         "--web-viewer-port", str(web_port)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        start_new_session=True,
    )  # fmt: skip
    atexit.register(_end, proc)
    local = "127.0.0.1" if bind in ("0.0.0.0", "::", "") else bind
    deadline = time.monotonic() + timeout
    while True:
        with socket.socket(socket.AF_INET6 if ":" in local else socket.AF_INET) as s:
            if s.connect_ex((local, grpc_port)) == 0:
                break
        if proc.poll() is not None or time.monotonic() > deadline:
            _end(proc)
            raise SystemExit(
                f"avs view: the rerun web server did not start on {bind}:{grpc_port} "
                f"(exit status {proc.poll()}): is the port taken? (--grpc-port, --web-port)"
            )
        time.sleep(0.1)
    host = socket.gethostname() if local != bind else ("localhost" if bind == "127.0.0.1" else bind)
    return f"rerun+http://{host}:{grpc_port}/proxy"


def _end(proc: subprocess.Popen) -> None:
    """End the rerun server and whatever it started (its process group, ``serve_web``)."""

    def group(sig: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)

    group(signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(5)
    group(signal.SIGKILL)  # what is left of it (the wrapper's child included)
    proc.wait(5)


def _view(args: argparse.Namespace) -> int:
    from avs.viewer import SceneLogger

    settings = settings_from(args, instance=args.instance)
    recording, notes = open_recording(args)
    logger = SceneLogger(cloud_stride=args.cloud_stride, map_block=args.map_block)
    with Node("view", settings, connect(settings), announce=False) as node:
        node.install_signal_handlers()
        viewer = Viewer(node, recording, logger, args.map_period)
        viewer.start()
        node.announce()  # alive: subscribed
        for note in notes:
            print(note, flush=True)
        node.spin(args.timeout or None)
        viewer.stop()
    recording.disconnect()
    dropped = node.metrics.dropped_total
    if dropped:
        print(f"avs view: dropped {dropped} invalid messages", file=sys.stderr)
    print(
        f"logged {viewer.logged} messages" + (f" to {args.save}" if args.save else "")
        + f"; {viewer.superseded} older ones skipped (the viewer draws the newest message of "
        "each stream, not every one that came while it drew)"
    )  # fmt: skip
    return 0
