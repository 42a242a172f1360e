"""Camera rate end to end (issues 18, 40): the live stack exactly as a user starts it, ``avs up
--scene kitchen`` with every other setting at its default (no ``AVS_*`` variable is passed on:
real time on the wall clock, every service a process, the gaze service running, the sim's
sensor models and the scene memory's view registration on, the camera at the sim's 15 fps),
moving along a scripted path: the platform drives sideways in front of the table and the
counter (0.1 m/s, 6 s each way) while a gaze target sweeps along them, so the gaze service pans
the head (±30° at ``--pan-deg-s``, 60°/s by default: 4° a frame at 15 fps, more than the scene
memory's keyframe threshold of 3°, so the keyframe policy skips frames only where the pan turns
around). Every service's kernels are put in the cache first (``avs warm-up``), so that no run
measures the services compiling them.

For every frame (by its ``seq``) this script, an outside client of ``avs up``'s router, takes
the time from its capture to
- its **observation**: perception's ``SceneObservation`` on ``perception/observation`` (its
  ``frame_seq``);
- the **semantic model**: the first scene memory ``SceneModel`` on ``memory/scene`` that holds
  that observation (it names every frame whose observation it is the first to hold:
  ``fused_frames``; the scene memory publishes one model for the observations that waited
  while it fused). ``fps_semantic`` counts these frames:
  an observation that never reached the model (dropped from the scene memory's queue, or
  never made) is not semantic, whatever happened to the frame's depth;
- the **map** that integrated its depth: after each integrated depth frame the scene memory
  publishes the view registration's ``PoseCorrection`` for it (``frame_seq``) on
  ``memory/pose_correction``. ``fps_mapped`` counts these frames; depth frames the keyframe
  policy skips (the camera moved < 3 cm and turned < 3°) or that a newer one replaced while the
  map was busy (newest first) are counted from the scene memory's metrics, not mapped.
Each stage is counted only where it happened: a frame mapped but never modelled counts in
``fps_mapped`` and not in ``fps_semantic``, and the other way round. A frame none of these took
within ``DRAIN_S`` after the run is not counted as reaching it.

Clock: in real time the sim stamps a frame with its *sim* clock (``world.time`` at capture:
seconds since the sim started, kept on the wall clock by its physics loop, which slips rather
than bursts when it falls 0.1 s behind; ``physics_slips`` in its metrics), not ``time.time()``.
Every arrival here is taken on ``time.monotonic()``; four times a second this script asks
``sim/control`` for the sim's status and keeps (sim_time, the query's midpoint on
``time.monotonic()``, round trip). A capture stamp is put on the monotonic clock by the
sample of the smallest round trip within ±1.5 s of it (sim time advancing at 1 s/s), so a
latency is off by at most half that round trip (printed: its median, typically 1-3 ms).

``fps_in`` is what the sim published (its metrics' ``messages_out`` on the camera's key over
the run). ``cpu_percent`` is the machine's busy time over the run from /proc/stat (100 = one
core; on a shared machine it includes others' load); each process's share is in the JSON.
Each stage's own timings come from the services' metrics queryables (``avs status``): the
scene memory's ``on_frame`` (map integration, registration, journal) and ``on_observation``
(fusion, encoding the scene model), and perception's per-frame ``timings_ms`` (carried in the
observations).

Writes ``OUT/pipeline.json`` (every frame's latencies, the counts, the stage timings, CPU per
process) and ``OUT/pipeline.png`` (latency over capture time per stage, and the rates); prints
progress every 5 s. The last line:

fps_in=<x> fps_semantic=<x> fps_mapped=<x> frame_to_semantic_p50_ms=<x>
frame_to_semantic_p99_ms=<x> frame_to_map_p50_ms=<x> frame_to_map_p99_ms=<x>
frame_to_observation_p50_ms=<x> cpu_percent=<x>

Targets (issue 40), in the default ``avs up`` on this 2-core machine: fps_semantic ≥ 5 and
frame_to_semantic_p50_ms ≤ 250.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from benchmarks._loopback import client_config, user_environment  # noqa: E402
from benchmarks.soak import cpu_table, drive, thread_ticks  # noqa: E402
from schemas import (  # noqa: E402
    GazeTarget,
    Keys,
    ServiceMetrics,
    SimControl,
    SimStatus,
    decode,
    encode,
)
from schemas.base import REGISTRY  # noqa: E402
from schemas.codec import peek  # noqa: E402

SCENE = "kitchen"
CAMERA = "head_rgbd"
#: seconds after the run in which late updates of the run's frames are still taken
DRAIN_S = 5.0
#: seconds after the stack is up and the path has started before the run is measured
SETTLE_S = 5.0
#: the gaze target's sweep: a line across the table and the counter, this far ahead of the
#: robot's start (m) and this high (m), the pan ±PAN_DEG about straight ahead
SWEEP_DISTANCE, SWEEP_HEIGHT, PAN_DEG = 2.3, 0.85, 30.0
#: what a frame may reach, each on its own: the observation, the semantic model, the map
STAGES = ("observation", "semantic", "map")


# -- the clock ------------------------------------------------------------------------------


@dataclass
class SimClock:
    """Samples of the sim's clock against this process's ``time.monotonic()``."""

    samples: list[tuple[float, float, float]] = field(default_factory=list)  # (sim, mono, rtt)

    def add(self, sim_time: float, sent: float, received: float) -> None:
        self.samples.append((sim_time, (sent + received) / 2, received - sent))

    def to_monotonic(self, stamp: float, window: float = 1.5) -> float | None:
        """``stamp`` (sim time) on the monotonic clock, by the sample of the smallest round trip
        within ``window`` seconds of sim time (else the nearest); None without samples."""
        if not self.samples:
            return None
        near = [s for s in self.samples if abs(s[0] - stamp) <= window]
        if near:
            sim, mono, _ = min(near, key=lambda s: s[2])
        else:
            sim, mono, _ = min(self.samples, key=lambda s: abs(s[0] - stamp))
        return mono + (stamp - sim)

    def rtt_ms(self) -> float:
        return float(np.median([s[2] for s in self.samples]) * 1e3) if self.samples else math.nan


# -- per-frame bookkeeping -------------------------------------------------------------------


@dataclass
class Frame:
    seq: int
    stamp: float | None  # capture, sim time (None until a message that carries it came)
    arrived: float | None = None  # the raw frame here (only with --frames)
    observation: float | None = None  # arrival times here, monotonic
    semantic: float | None = None  # the first SceneModel that fused its observation
    map: float | None = None  # the PoseCorrection published once its depth was integrated


class Ledger:
    """Arrival times of every frame's products, from Zenoh's callbacks."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.frames: dict[int, Frame] = {}
        self.perception_ms: dict[str, list[float]] = defaultdict(list)
        self.invalid = 0

    def _frame(self, seq: int, stamp: float | None) -> Frame:
        f = self.frames.get(seq)
        if f is None:
            f = self.frames[seq] = Frame(seq, stamp)
        elif f.stamp is None:  # a model named it before its observation or map came
            f.stamp = stamp
        return f

    def note(self, stage: str, seq: int, stamp: float | None, at: float) -> None:
        with self.lock:
            f = self._frame(seq, stamp)
            if getattr(f, stage) is None:  # the first that includes it
                setattr(f, stage, at)

    def snapshot(self) -> list[Frame]:
        with self.lock:
            return [Frame(**vars(f)) for f in self.frames.values()]


#: the fields this meter reads of each message (the rest is skipped, not decoded: a kitchen
#: SceneModel is 3 MB, six a second)
FIELDS = ("schema", "version", "camera", "frame_seq", "frame_stamp", "stamp", "timings_ms",
          "fused_frames")  # fmt: skip


def _message(payload: bytes, schema: str) -> dict | None:
    """The fields this meter reads of a message of ``schema`` at its current version (not
    validated: only seq and stamps are read), else None."""
    m = peek(payload, *FIELDS, limit=None)
    if m.get("schema") != schema:
        return None
    return m if m.get("version") == REGISTRY[schema].VERSION else None


def subscribe(session: zenoh.Session, keys: Keys, ledger: Ledger, frames: bool) -> list:
    def on_observation(sample: zenoh.Sample) -> None:
        at = time.monotonic()
        m = _message(sample.payload.to_bytes(), "SceneObservation")
        if m is None or m.get("camera") != CAMERA:
            ledger.invalid += 1
            return
        ledger.note("observation", m["frame_seq"], m["frame_stamp"], at)
        with ledger.lock:
            for k, v in (m.get("timings_ms") or {}).items():
                ledger.perception_ms[k].append(float(v))

    def on_model(sample: zenoh.Sample) -> None:
        at = time.monotonic()
        m = _message(sample.payload.to_bytes(), "SceneModel")
        if m is None:
            ledger.invalid += 1
        else:  # every frame whose observation it is the first model to hold (v3)
            for seq in m.get("fused_frames") or []:
                ledger.note("semantic", seq, None, at)

    def on_correction(sample: zenoh.Sample) -> None:
        at = time.monotonic()
        m = _message(sample.payload.to_bytes(), "PoseCorrection")
        if m is None or m.get("camera") != CAMERA:
            ledger.invalid += 1
            return
        ledger.note("map", m["frame_seq"], m["stamp"], at)

    def on_frame(sample: zenoh.Sample) -> None:
        at = time.monotonic()
        head = peek(sample.payload.to_bytes(), "seq", "stamp")  # the 2 MB frame not decoded
        if len(head) == 2:
            ledger.note("arrived", head["seq"], head["stamp"], at)

    subs = [
        session.declare_subscriber(keys.observation(), on_observation),
        session.declare_subscriber(keys.scene(), on_model),
        session.declare_subscriber(keys.pose_correction(), on_correction),
    ]
    if frames:
        subs.append(session.declare_subscriber(keys.rgbd(CAMERA), on_frame))
    return subs


# -- the scripted path -----------------------------------------------------------------------


def sweep_gaze(
    session: zenoh.Session, keys: Keys, pan_deg_s: float, stop: threading.Event, hz: float = 30
) -> None:
    """A manual gaze target moving along a line across the table and the counter: the pan
    angle (seen from the robot's start) a triangle wave of ±PAN_DEG at ``pan_deg_s``."""
    pub = session.declare_publisher(keys.gaze_target())
    t0, seq = time.monotonic(), 0
    period = 4 * PAN_DEG / pan_deg_s
    while not stop.wait(1.0 / hz):
        phase = ((time.monotonic() - t0) / period) % 1.0
        pan = math.radians(PAN_DEG * (4 * phase - 1 if phase < 0.5 else 3 - 4 * phase))
        point = (SWEEP_DISTANCE, SWEEP_DISTANCE * math.tan(pan), SWEEP_HEIGHT)
        seq += 1
        pub.put(encode(GazeTarget(seq=seq, stamp=time.time(), point=point, source="manual",
                                  priority=10.0, hold_s=1.0)))  # fmt: skip


def watch_clock(session: zenoh.Session, keys: Keys, clock: SimClock, stop: threading.Event):
    query = encode(SimControl(op="status"))
    while not stop.wait(0.25):
        sent = time.monotonic()
        try:
            replies = list(session.get(keys.sim_control(), payload=query, timeout=2.0))
        except zenoh.ZError:
            continue
        received = time.monotonic()
        for r in replies:
            if r.ok is not None:
                status = decode(r.ok.payload.to_bytes(), SimStatus)
                clock.add(status.sim_time, sent, received)


def wait_active(session: zenoh.Session, keys: Keys, services: set[str], timeout: float) -> bool:
    """Wait until every service of ``services`` has an active liveliness token (the scene
    memory's comes once its kernels are warm, after ``avs up`` may have said it is ready: a
    standby token is not enough); print what is still missing every 10 s."""
    deadline, said = time.monotonic() + timeout, time.monotonic()
    while time.monotonic() < deadline:
        tokens = {str(r.ok.key_expr).split("/")[3] for r in session.liveliness().get(keys.alive())
                  if r.ok is not None}  # fmt: skip
        missing = services - tokens
        if not missing:
            return True
        if time.monotonic() - said >= 10:
            print(f"  waiting for {', '.join(sorted(missing))} …", flush=True)
            said = time.monotonic()
        time.sleep(0.5)
    return False


def metrics(session: zenoh.Session, keys: Keys) -> dict[str, ServiceMetrics]:
    """Every service instance's metrics now, by instance (asked again where one is missing:
    a loaded machine may miss an answer)."""
    out: dict[str, ServiceMetrics] = {}
    for _ in range(3):
        for r in session.get(keys.metrics(), timeout=3):
            if r.ok is not None:
                m = decode(r.ok.payload.to_bytes(), ServiceMetrics)
                out[m.instance] = m
        if {"sim", "perception", "scene_memory"} <= {m.service for m in out.values()}:
            break
    return out


def active_memory(ms: dict[str, ServiceMetrics]) -> ServiceMetrics | None:
    """The scene memory instance that works (the other stands by)."""
    memories = [m for m in ms.values() if m.service == "scene_memory"]
    return max(memories, key=lambda m: sum(m.messages_valid.values()), default=None)


# -- the figures -----------------------------------------------------------------------------


def pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 1) if values else math.nan


def latencies(
    frames: list[Frame], clock: SimClock, t0: float, t1: float
) -> tuple[list[dict], dict]:
    """Per frame captured in [t0, t1) (monotonic): capture time (s from t0) and each stage's
    latency (ms, None where the stage did not take it); and per stage the latencies."""
    rows, per_stage = [], defaultdict(list)
    for f in sorted(frames, key=lambda f: f.seq):
        captured = None if f.stamp is None else clock.to_monotonic(f.stamp)
        if captured is None or not t0 <= captured < t1:
            continue
        row = {"seq": f.seq, "t": round(captured - t0, 3)}
        for stage in ("arrived", *STAGES):
            at = getattr(f, stage)
            if at is not None:
                ms = (at - captured) * 1e3
                row[stage] = round(ms, 1)
                per_stage[stage].append(ms)
            else:
                row[stage] = None
        rows.append(row)
    return rows, per_stage


def counter(m: ServiceMetrics | None, what: str, name: str) -> float:
    if m is None:
        return 0.0
    return float(getattr(m, what).get(name, 0))


def plot(rows: list[dict], rates: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    style = {
        "arrived": ("C7", "frame published"),
        "observation": ("C0", "observation"),
        "semantic": ("C3", "semantic model"),
        "map": ("C1", "map"),
    }
    for stage, (colour, label) in style.items():
        pts = [(r["t"], r[stage]) for r in rows if r.get(stage) is not None]
        if pts:
            t, ms = zip(*pts, strict=True)
            axes[0].plot(t, ms, ".-" if stage == "semantic" else ".", c=colour, ms=3, lw=0.6,
                         label=f"{label} (p50 {np.median(ms):.0f} ms)")  # fmt: skip
    axes[0].axhline(250, ls=":", c="k", lw=0.8)
    axes[0].set_yscale("log")
    axes[0].set(ylabel="ms after capture (log)", title="frame → stage latency, per frame")
    axes[0].legend(fontsize=8, loc="upper left")
    if rates:
        t = [r["t"] for r in rates]
        for key, label in (("in", "frames published"), ("observed", "observed"),
                           ("semantic", "in the semantic model"), ("mapped", "in the map"),
                           ("skipped", "keyframe-skipped")):  # fmt: skip
            axes[1].plot(t, [r[key] for r in rates], "o-", ms=3, label=label)
        axes[1].axhline(5, ls=":", c="k", lw=0.8)
    axes[1].set(xlabel="capture time, s", ylabel="frames / s", title="rates (per 5 s)")
    axes[1].legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def rates_by_window(rows: list[dict], duration: float, marks: list, step: float = 5.0):
    """Per second in windows of ``step`` s: frames the sim published and the keyframe policy
    skipped (from the metrics taken as the run went: ``marks`` of (t, published, skipped)),
    and frames observed, in the semantic model and in the map (by capture time)."""
    out = []
    for a in np.arange(0.0, duration - 1.0, step):
        b = min(a + step, duration)
        w = [r for r in rows if a <= r["t"] < b]
        m = [x for x in marks if a - 0.5 <= x[0] <= b + 0.5]
        span = (m[-1][0] - m[0][0]) if len(m) > 1 else 0.0
        out.append({
            "t": round(float(a + b) / 2, 1),
            "in": round((m[-1][1] - m[0][1]) / span, 2) if span > 0 else math.nan,
            "observed": round(sum(r["observation"] is not None for r in w) / (b - a), 2),
            "semantic": round(sum(r["semantic"] is not None for r in w) / (b - a), 2),
            "mapped": round(sum(r["map"] is not None for r in w) / (b - a), 2),
            "skipped": round((m[-1][2] - m[0][2]) / span, 2) if span > 0 else math.nan,
        })  # fmt: skip
    return out


def proc_stat() -> tuple[int, int]:
    """(busy, total) jiffies of the whole machine so far."""
    values = [int(v) for v in Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]]
    idle = values[3] + (values[4] if len(values) > 4 else 0)  # idle + iowait
    total = sum(values[:8])  # user … steal (guest time is already in user)
    return total - idle, total


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--duration", type=float, default=60.0, help="seconds measured (default 60)")
    p.add_argument("--scene", default=SCENE, help=f"avs up --scene (default {SCENE})")
    p.add_argument("--pan-deg-s", type=float, default=60.0,
                   help="the head's pan speed along the sweep, °/s (default 60)")  # fmt: skip
    p.add_argument("--out", type=Path, default=Path("pipeline"))
    p.add_argument("--port", type=int, default=7463)
    p.add_argument("--frames", action="store_true",
                   help="also subscribe to the RGB-D frames (2 MB each) to time capture → "
                   "published; off by default: it loads the router and this process")  # fmt: skip
    args = p.parse_args()
    if args.duration <= 0 or args.pan_deg_s <= 0:
        p.error("--duration and --pan-deg-s must be > 0")
    args.out.mkdir(parents=True, exist_ok=True)
    data = args.out / "data"
    shutil.rmtree(data, ignore_errors=True)  # a fresh map: nothing restored from a last run
    endpoint, keys = f"tcp/127.0.0.1:{args.port}", Keys("armar6")
    env = user_environment()
    # every service's kernels in the cache first (seconds when they are; a minute or more after
    # a kernel changed): otherwise the services compile at their start, on the cores the run
    # then measures, and the first run after a change measures the compiler
    subprocess.run([sys.executable, "-m", "avs.cli", "warm-up"], env=env, check=True)
    command = args.avs_up = ["up", "--scene", args.scene, "--listen", endpoint, "--data-dir",
                             str(data)]  # fmt: skip
    print(f"starting avs {' '.join(command)}: the stack as a user starts it, every setting at "
          "its default (no AVS_* variable passed on) …", flush=True)  # fmt: skip
    started = time.monotonic()
    up = subprocess.Popen(
        [sys.executable, "-P", "-m", "avs.cli", "--log-level", "WARNING", *command],
        stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env,
    )  # fmt: skip
    try:
        return run(args, up, endpoint, keys, started)
    finally:
        if up.poll() is None:
            up.send_signal(signal.SIGINT)
            try:
                up.wait(60)
            except subprocess.TimeoutExpired:
                up.kill()


def run(args, up: subprocess.Popen, endpoint: str, keys: Keys, started: float) -> int:
    line = up.stdout.readline()
    if not line:
        print("avs up exited before it was ready", file=sys.stderr)
        return 1
    ready = json.loads(line)
    print(f"avs up ready in {time.monotonic() - started:.0f} s: "
          f"{[(c['instance'], c['alive']) for c in ready['services']]}", flush=True)  # fmt: skip
    labels = {c["pid"]: c["instance"] for c in ready["services"] if c["pid"]}
    labels |= {up.pid: "router (avs up)", os.getpid(): "pipeline meter"}
    ledger, clock, stop = Ledger(), SimClock(), threading.Event()
    with zenoh.open(client_config(endpoint)) as session:
        services = {c["service"] for c in ready["services"]}
        if not wait_active(session, keys, services, timeout=300):
            print("not every service became active within 300 s", file=sys.stderr)
            return 1
        print(f"every service active {time.monotonic() - started:.0f} s after the start",
              flush=True)  # fmt: skip
        subs = subscribe(session, keys, ledger, args.frames)
        jobs = ((drive, (session, keys, stop)),
                (sweep_gaze, (session, keys, args.pan_deg_s, stop)),
                (watch_clock, (session, keys, clock, stop)))  # fmt: skip
        threads = [threading.Thread(target=f, args=a, daemon=True) for f, a in jobs]
        for t in threads:
            t.start()
        time.sleep(SETTLE_S)  # the gaze turns to the sweep, the platform gets going
        m0 = metrics(session, keys)
        busy0, ticks0 = proc_stat(), thread_ticks(labels)
        t0 = time.monotonic()
        rgbd = keys.rgbd(CAMERA)

        def mark(t: float, ms: dict[str, ServiceMetrics]) -> tuple[float, float, float]:
            sim = next((m for m in ms.values() if m.service == "sim"), None)
            return (t, counter(sim, "messages_out", rgbd),
                    counter(active_memory(ms), "extra", "frames_skipped"))  # fmt: skip

        marks = [mark(0.0, m0)]
        next_report = t0 + 5.0
        while (now := time.monotonic()) < t0 + args.duration:
            time.sleep(max(0.0, min(next_report, t0 + args.duration) - now))
            now = time.monotonic()
            if now >= next_report or now >= t0 + args.duration:
                next_report += 5.0
                rows, per = latencies(ledger.snapshot(), clock, t0, now)
                marks.append(mark(now - t0, metrics(session, keys)))
                published, skipped = (marks[-1][i] - marks[0][i] for i in (1, 2))
                print(f"  {now - t0:5.1f}/{args.duration:g} s: published {published:.0f}, "
                      f"observed {len(per['observation'])}, semantic {len(per['semantic'])}, "
                      f"mapped {len(per['map'])}, keyframe-skipped {skipped:.0f}; p50 ms: "
                      f"observation {pct(per['observation'], 50)}, semantic "
                      f"{pct(per['semantic'], 50)}, map {pct(per['map'], 50)}",
                      flush=True)  # fmt: skip
        t1 = time.monotonic()
        busy1, ticks1 = proc_stat(), thread_ticks(labels)
        m1 = metrics(session, keys)
        print(f"draining {DRAIN_S:g} s (late updates of the run's frames) …", flush=True)
        time.sleep(DRAIN_S)
        stop.set()
        for s in subs:
            s.undeclare()
        for t in threads:
            t.join(5)
    elapsed = t1 - t0
    cpu_percent = round(100 * os.cpu_count() * (busy1[0] - busy0[0]) / max(1, busy1[1] - busy0[1]),
                        1)  # fmt: skip
    processes = cpu_table(ticks0, ticks1, elapsed)
    ours = round(sum(sum(t.values()) for t in processes.values()), 1)
    load = [round(x, 2) for x in os.getloadavg()]
    rows, per = latencies(ledger.snapshot(), clock, t0, t1)
    sim0 = next((m for m in m0.values() if m.service == "sim"), None)
    sim1 = next((m for m in m1.values() if m.service == "sim"), None)
    published = counter(sim1, "messages_out", rgbd) - counter(sim0, "messages_out", rgbd)
    span = (sim1.stamp - sim0.stamp) if sim0 and sim1 else elapsed
    fps_in = published / span if published > 0 else len(rows) / elapsed
    mem0, mem1 = active_memory(m0), active_memory(m1)
    per0 = next((m for m in m0.values() if m.service == "perception"), None)
    per1 = next((m for m in m1.values() if m.service == "perception"), None)

    def delta(a, b, what, name):
        return counter(b, what, name) - counter(a, what, name)

    counts = {
        "frames_published": int(published),
        "frames_captured_seen": len(rows),
        "observed": len(per["observation"]),
        "semantic": len(per["semantic"]),
        "mapped": len(per["map"]),
        "keyframe_skipped": int(delta(mem0, mem1, "extra", "frames_skipped")),
        # integrated frames placed by the last correction (registration at most every
        # --registration-interval), and those registration refused
        "registration_not_due": int(delta(mem0, mem1, "extra", "registrations_not_due")),
        "registration_refused": int(delta(mem0, mem1, "extra", "registrations_refused")),
        "memory_superseded": int(delta(mem0, mem1, "dropped", "superseded")),
        "perception_superseded": int(delta(per0, per1, "dropped", "superseded")),
        "perception_stale": int(delta(per0, per1, "dropped", "stale")),
        "physics_slips": int(delta(sim0, sim1, "extra", "physics_slips")),
        "invalid_messages_here": ledger.invalid,
    }
    stages = {}
    if mem1 is not None:
        handlers = {k: v.model_dump() for k, v in mem1.processing_ms.items()
                    if k in ("on_frame", "on_observations")}  # fmt: skip
        gauges = {"last_" + k: round(v, 1) for k, v in mem1.extra.items() if k.endswith("_ms")}
        stages["scene_memory"] = handlers | gauges
    stages["perception_ms_p50"] = {k: pct(v, 50) for k, v in sorted(ledger.perception_ms.items())}
    stages["perception_ms_p99"] = {k: pct(v, 99) for k, v in sorted(ledger.perception_ms.items())}
    summary = {
        "fps_in": round(fps_in, 2),
        "fps_semantic": round(len(per["semantic"]) / elapsed, 2),
        "fps_mapped": round(len(per["map"]) / elapsed, 2),
        "frame_to_semantic_p50_ms": pct(per["semantic"], 50),
        "frame_to_semantic_p99_ms": pct(per["semantic"], 99),
        "frame_to_map_p50_ms": pct(per["map"], 50),
        "frame_to_map_p99_ms": pct(per["map"], 99),
        "frame_to_observation_p50_ms": pct(per["observation"], 50),
        "cpu_percent": cpu_percent,
    }
    detail = {
        stage: {"n": len(per[stage]), "p50_ms": pct(per[stage], 50),
                "p90_ms": pct(per[stage], 90), "p99_ms": pct(per[stage], 99),
                "fps": round(len(per[stage]) / elapsed, 2)}
        for stage in ("arrived", *STAGES) if per[stage]
    }  # fmt: skip
    rates = rates_by_window(rows, elapsed, marks)
    (args.out / "pipeline.json").write_text(json.dumps({
        "summary": summary, "stages": detail, "counts": counts, "stage_timings": stages,
        "cpu_percent_by_process": processes, "cpu_percent_stack": ours,
        "loadavg_at_end": load, "clock_rtt_ms_p50": round(clock.rtt_ms(), 2),
        "duration_s": round(elapsed, 2), "pan_deg_s": args.pan_deg_s,
        "scene": args.scene, "avs_up": args.avs_up, "rates": rates, "frames": rows,
    }, indent=1))  # fmt: skip
    plot(rows, rates, args.out / "pipeline.png")
    print(f"clock: sim time put on this process's clock by status queries (round trip p50 "
          f"{clock.rtt_ms():.1f} ms)")  # fmt: skip
    print("per stage (ms after capture; fps of frames that reached it):")
    for stage, d in detail.items():
        print(f"  {stage}: n {d['n']}, {d['fps']}/s, p50 {d['p50_ms']}, p90 {d['p90_ms']}, "
              f"p99 {d['p99_ms']}")  # fmt: skip
    print("counts: " + ", ".join(f"{k} {v}" for k, v in counts.items()))
    if "scene_memory" in stages:
        sm = stages["scene_memory"]
        for name in ("on_frame", "on_observations"):
            if name in sm:
                print(f"scene memory {name}: p50 {sm[name]['p50']:.0f} ms, p99 "
                      f"{sm[name]['p99']:.0f} ms (n {sm[name]['count']})")  # fmt: skip
    p50 = stages["perception_ms_p50"]
    if p50:
        print("perception per frame, p50 ms: " + ", ".join(f"{k} {v}" for k, v in p50.items()))
    print("CPU (% of one core over the run): " + ", ".join(
        f"{label} {sum(t.values()):.0f}" for label, t in
        sorted(processes.items(), key=lambda kv: -sum(kv[1].values()))))  # fmt: skip
    print(f"the stack and this meter took {ours:.0f} % of the machine's {cpu_percent:.0f} % "
          f"(the rest: other processes on this machine; load average {load})")  # fmt: skip
    print(f"wrote {args.out / 'pipeline.json'} and {args.out / 'pipeline.png'}")
    print(" ".join(f"{k}={v}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
