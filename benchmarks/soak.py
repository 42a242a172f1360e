"""The live stack under load for ``--minutes`` (issues 14, 40): ``avs up`` exactly as a user
starts it (every setting at its default: no ``AVS_*`` variable of this process is passed on;
real time, every service a process, the sim on the wall clock, the sensor models and view
registration on, perception at avs up's rate), ARMAR-6 driving a scripted path (sideways back
and forth at 0.1 m/s) while the gaze holds a fixation target on the table, this
script as an outside subscriber, and a garbage publisher (its own process) putting 100 msgs/s
on every input key: random bytes, valid messages of the wrong schema, the right schema with a
wrong version.

The 1 kHz rates are counted where they are consumed, valid messages only: the IMU samples that
reached the gaze whole (``messages_valid`` of ``sensors/imu`` in its metrics: taken by its
control loop, or replaced by a newer one that came while a step ran; the steps themselves are
``control_hz``) and the head commands the sim applied (``cmd/head`` in its metrics), read once
a minute. (An outside subscriber of both 1 kHz streams costs this
2-core machine about a quarter of a core in Zenoh's threads alone, a load no user's viewer puts
on a robot; ``--outside-1khz`` adds it, counted the same way.) The outside subscriber here takes
what a viewer takes: every RGB-D frame, the observations and the scene model, at ordinary
priority, counting valid messages by their schema and version. The gaze error is the angle
between the head camera's optical axis and the direction to the target, both from the sim's
ground truth (the true camera pose, not the odometry's), asked ten times a second. Per minute
it prints IMU, ``cmd/head`` and observation rates, scene updates, the gaze error's p50 and
p99; writes ``DIR/soak.json`` and ``DIR/soak.png``. The last line:

minutes=<n> imu_hz_min=<x> cmd_head_hz_min=<x> observation_hz_min=<x>
scene_updates_per_min_min=<x> token_flaps=<n> restarts=<n> rss_growth_mb=<x>
gaze_error_deg_p99=<x> reference_perception_ms=<x>

The last is the machine's speed: perception's CPU time on one frame of the scene alone, before
and after the run (the larger). A shared machine's speed changes by half within an hour, and the
rates with it: read them against it. Each minute's row also holds each process's CPU.

Targets (issues 14, 40), in that default configuration: IMU ≥ 950 Hz and cmd/head ≥ 900 Hz in
every minute, observations ≥ 5 Hz, scene updates every minute, 0 token flaps, 0 restarts, RSS
growth ≤ 100 MB, p99 ≤ 1°.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import msgpack
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import zenoh  # noqa: E402

from benchmarks._loopback import client_config, user_environment  # noqa: E402
from schemas import (  # noqa: E402
    BaseVelocity,
    GazeTarget,
    GroundTruth,
    GroundTruthQuery,
    HeadCommand,
    ImuSample,
    Keys,
    ServiceMetrics,
    SupervisorStatus,
    decode,
    encode,
)
from schemas.codec import peek  # noqa: E402
from services.common.realtime import prioritise  # noqa: E402

#: the input keys the garbage goes to, and a valid message of another schema for each
INPUT_KEYS = ("sensors/rgbd/head_rgbd", "sensors/imu", "state/joints", "state/base", "cmd/base",
              "cmd/head", "perception/observation", "gaze/target")  # fmt: skip
GARBAGE_HZ = 100.0


def _session(endpoint: str) -> zenoh.Session:
    return zenoh.open(client_config(endpoint))


def garbage(endpoint: str, robot: str, stop: mp.Event) -> None:
    """100 msgs/s on every input key, cycling through three kinds of bad payloads."""
    rng = np.random.default_rng(7)
    keys = Keys(robot)
    imu = ImuSample(
        seq=1, stamp=0.0, angular_velocity=np.zeros(3), linear_acceleration=np.zeros(3),
        orientation=np.array([1.0, 0, 0, 0]),
    )  # fmt: skip
    head = encode(HeadCommand(seq=1, stamp=0.0, names=["x"], mode="position", values=np.zeros(1)))

    def wrong_version(payload: bytes) -> bytes:
        m = msgpack.unpackb(payload, raw=False)
        m["version"] = 99
        return msgpack.packb(m, use_bin_type=True)

    pool = [
        lambda _k: rng.bytes(int(rng.integers(1, 300))),
        lambda k: head if k.endswith("sensors/imu") else encode(imu),  # the wrong schema
        lambda k: wrong_version(encode(imu) if not k.endswith("sensors/imu") else head),
    ]
    with _session(endpoint) as session:
        pubs = [session.declare_publisher(keys.key(k)) for k in INPUT_KEYS]
        period, i, t = 1.0 / GARBAGE_HZ, 0, time.monotonic()
        while not stop.is_set():
            for p in pubs:
                p.put(pool[i % len(pool)](str(p.key_expr)))
            i += 1
            t += period
            time.sleep(max(0.0, t - time.monotonic()))


class Meter:
    """The outside subscriber (valid messages per key and minute), the gaze error against the
    sim's ground truth, token flaps."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, target: np.ndarray, outside_1khz: bool
    ) -> None:
        self.session, self.keys = session, keys
        self.lock = threading.Lock()
        self.counts: dict[str, int] = defaultdict(int)
        self.errors: list[float] = []
        self.flaps: list[str] = []
        self.target = target
        expect = {keys.rgbd("head_rgbd"): "RgbdFrame", keys.observation(): "SceneObservation",
                  keys.scene(): "SceneModel"}  # fmt: skip
        if outside_1khz:
            expect |= {keys.imu(): "ImuSample", keys.cmd_head(): "HeadCommand"}
        self.subs = [session.declare_subscriber(k, self._counter(k, s)) for k, s in expect.items()]
        self.subs.append(session.liveliness().declare_subscriber(keys.alive(), self._token))
        self.watching_tokens = True

    def _counter(self, key: str, schema: str):
        from schemas.base import REGISTRY

        version = REGISTRY[schema].VERSION

        def on(sample: zenoh.Sample) -> None:
            head = peek(sample.payload.to_bytes(), "schema", "version")
            if head.get("schema") == schema and head.get("version") == version:
                with self.lock:
                    self.counts[key] += 1

        return on

    def watch_gaze(self, stop: threading.Event, period: float = 0.1) -> None:
        """The gaze error ten times a second: the true camera pose from the sim's ground truth
        (no segmentation, no support graph: a cheap query)."""
        query = encode(GroundTruthQuery(camera="head_rgbd", segmentation=False, support=False))
        while not stop.wait(period):
            try:
                replies = list(self.session.get(self.keys.ground_truth(), payload=query,
                                                timeout=2.0))  # fmt: skip
            except zenoh.ZError:
                continue
            for r in replies:
                if r.ok is None:
                    continue
                T = decode(r.ok.payload.to_bytes(), GroundTruth).T_world_camera
                to = self.target - T[:3, 3]
                cos = float(np.dot(T[:3, 2], to) / np.linalg.norm(to))
                with self.lock:
                    self.errors.append(math.degrees(math.acos(min(1.0, max(-1.0, cos)))))

    def _token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.DELETE and self.watching_tokens:
            with self.lock:
                self.flaps.append(str(sample.key_expr))

    def take(self) -> tuple[dict[str, int], list[float]]:
        with self.lock:
            counts, errors = dict(self.counts), self.errors
            self.counts, self.errors = defaultdict(int), []
        return counts, errors


def consumed(session: zenoh.Session, keys: Keys) -> dict[str, tuple[int, float]]:
    """(valid messages taken so far, the metrics' stamp) of the IMU at the gaze and of
    ``cmd/head`` at the sim, from their metrics queryables (None where one did not answer)."""
    out: dict[str, tuple[int, float]] = {}
    for service, key, name in (("gaze", keys.imu(), "imu"), ("sim", keys.cmd_head(), "cmd_head")):
        for _ in range(3):  # asked again: a loaded machine may miss one answer
            replies = [r for r in session.get(keys.metrics(service, "*"), timeout=3) if r.ok]
            if replies:
                m = decode(replies[0].ok.payload.to_bytes(), ServiceMetrics)
                out[name] = (m.messages_valid.get(key, 0), m.stamp)
                if service == "gaze":
                    out["control"] = (int(m.extra.get("control_steps", 0)), m.stamp)
                break
    return out


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def thread_ticks(pids: dict[int, str]) -> dict[tuple[str, str], int]:
    """CPU ticks (user + system) so far of every thread of the given processes, keyed by
    (process label, thread name): threads of one name are summed (Zenoh's rx-0, rx-1 …)."""
    out: dict[tuple[str, str], int] = defaultdict(int)
    for pid, label in pids.items():
        for task in Path(f"/proc/{pid}/task").glob("*"):
            try:
                comm = (task / "comm").read_text().strip()
                fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            out[(label, comm.rstrip("0123456789-") or comm)] += int(fields[11]) + int(fields[12])
    return out


def cpu_table(before: dict, after: dict, seconds: float) -> dict[str, dict[str, float]]:
    """Per process, its threads' CPU over the interval in % of one core, largest first."""
    hz = os.sysconf("SC_CLK_TCK")
    table: dict[str, dict[str, float]] = defaultdict(dict)
    for (label, thread), ticks in after.items():
        share = 100 * (ticks - before.get((label, thread), 0)) / hz / seconds
        if share >= 0.5:
            table[label][thread] = round(share, 1)
    return {label: dict(sorted(t.items(), key=lambda kv: -kv[1])) for label, t in table.items()}


def host_reference(out: mp.Queue, repeats: int = 9) -> None:
    """The machine's speed now: perception's CPU time on one frame of the soak's scene, from
    the robot's start, alone (median of ``repeats``). Shared machines change speed by half
    within an hour; the soak's rates are read against it."""
    from services.perception.pipeline import Perception
    from services.sim import capture
    from services.sim.render import CameraRenderer
    from services.sim.robots import ARMAR6
    from services.sim.world import World, look_target

    world = World("tabletop_occluded", ARMAR6)
    world.look_at(look_target(world))
    renderer = CameraRenderer(world.model, 640, 480)
    frame, _ = capture.view(world, renderer, "head_rgbd", np.random.default_rng(0))
    renderer.close()
    perception = Perception()
    perception.warm_up()
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        perception.perceive(frame.depth, frame.rgb, frame.intrinsics, frame.T_world_camera)
        times.append((time.process_time() - t0) * 1e3)
    out.put(round(float(np.median(times)), 1))


def reference_ms() -> float:
    """``host_reference`` in a process of its own (the meter stays small)."""
    ctx = mp.get_context("spawn")
    q: mp.Queue = ctx.Queue()
    proc = ctx.Process(target=host_reference, args=(q,))
    proc.start()
    ms = q.get(timeout=300)
    proc.join(30)
    return ms


def supervised(session: zenoh.Session, keys: Keys) -> SupervisorStatus | None:
    for _ in range(3):  # asked again: a loaded machine may miss one answer
        for r in session.get(keys.supervisor(), timeout=3):
            if r.ok:
                return decode(r.ok.payload.to_bytes(), SupervisorStatus)
    return None


def drive(session: zenoh.Session, keys: Keys, stop: threading.Event) -> None:
    """The scripted path: sideways at 0.1 m/s, 6 s each way (0.6 m), commanded at 20 Hz: the
    fixation target stays within the head's reach while the platform moves under it."""
    pub = session.declare_publisher(keys.cmd_base())
    t0, seq = time.monotonic(), 0
    while not stop.wait(0.05):
        t = time.monotonic() - t0
        sign = 1.0 if int(t // 6) % 2 == 0 else -1.0
        seq += 1
        pub.put(encode(BaseVelocity(seq=seq, stamp=time.time(), v_x=0.0, v_y=0.1 * sign,
                                    timeout=0.5)))  # fmt: skip
    pub.put(encode(BaseVelocity(seq=seq + 1, stamp=time.time(), v_x=0.0)))


def hold_gaze(session: zenoh.Session, keys: Keys, target: np.ndarray, stop: threading.Event):
    pub = session.declare_publisher(keys.gaze_target())
    seq = 0
    while True:
        seq += 1
        pub.put(encode(GazeTarget(seq=seq, stamp=time.time(), point=target, source="manual",
                                  priority=10.0, hold_s=5.0)))  # fmt: skip
        if stop.wait(1.0):
            return


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = [r["minute"] for r in rows]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot(m, [r["imu_hz"] for r in rows], "o-", label="IMU")
    axes[0].plot(m, [r["cmd_head_hz"] for r in rows], "s-", label="cmd/head")
    axes[0].axhline(950, ls=":", c="C0")
    axes[0].axhline(900, ls=":", c="C1")
    axes[0].set(xlabel="minute", ylabel="Hz", title="1 kHz streams")
    axes[0].legend()
    axes[1].plot(m, [r["observation_hz"] for r in rows], "o-", label="observations (Hz)")
    axes[1].plot(m, [r["scene_updates"] / 60 for r in rows], "s-", label="scene updates (/s)")
    axes[1].axhline(5, ls=":", c="C0")
    axes[1].set(xlabel="minute", title="perception and memory")
    axes[1].legend()
    axes[2].plot(m, [r["gaze_error_deg_p99"] for r in rows], "o-")
    axes[2].axhline(1.0, ls=":")
    axes[2].set(xlabel="minute", ylabel="degrees", title="gaze error p99")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=int, default=10)
    p.add_argument("--out", type=Path, default=Path("soak"))
    p.add_argument("--port", type=int, default=7461)
    p.add_argument("--no-garbage", action="store_true", help="without the garbage publisher")
    p.add_argument("--scale", default="", metavar="NAME=N,…",
                   help="avs up --scale (e.g. perception=2)")  # fmt: skip
    p.add_argument("--outside-1khz", action="store_true",
                   help="the outside subscriber also takes sensors/imu and cmd/head (its counts "
                   "are in the rows as outside_imu_hz, outside_cmd_head_hz)")  # fmt: skip
    args = p.parse_args()
    if args.minutes < 1:
        p.error("--minutes must be ≥ 1")
    args.out.mkdir(parents=True, exist_ok=True)
    from experiments.episode import scene_facts

    facts = scene_facts("tabletop_occluded", "armar6")
    target = np.asarray(facts.centre, float)
    endpoint, keys = f"tcp/127.0.0.1:{args.port}", Keys("armar6")
    env = user_environment()
    os.environ.setdefault("MUJOCO_GL", "egl")
    reference_before = reference_ms()
    print(f"the machine now: perception takes {reference_before} ms of CPU on one frame alone",
          flush=True)  # fmt: skip
    command = ["up", "--listen", endpoint, "--data-dir", str(args.out / "data"),
               *(["--scale", args.scale] if args.scale else [])]  # fmt: skip
    print(f"starting avs {' '.join(command)}: the stack as a user starts it, every setting at "
          "its default (no AVS_* variable passed on)", flush=True)  # fmt: skip
    up = subprocess.Popen(
        [sys.executable, "-P", "-m", "avs.cli", "--log-level", "WARNING", *command],
        stdout=subprocess.PIPE, text=True, cwd=ROOT, env=env,
    )  # fmt: skip
    ready = json.loads(up.stdout.readline())
    print(f"avs up: {[(c['instance'], c['alive']) for c in ready['services']]}", flush=True)
    started = [c["pid"] for c in ready["services"] if c["pid"]]
    stop_garbage = mp.get_context("spawn").Event()
    junk = None
    if not args.no_garbage:
        junk = mp.get_context("spawn").Process(
            target=garbage, args=(endpoint, "armar6", stop_garbage), daemon=True
        )
        junk.start()
    stop = threading.Event()
    rows: list[dict] = []
    rss_start: dict[int, float] = {}
    all_errors: list[float] = []
    with _session(endpoint) as session:
        if args.outside_1khz:  # its Zenoh threads keep up with 2 kHz (it must not undercount)
            prioritise("the soak meter", main_thread=False)
        meter = Meter(session, keys, target, args.outside_1khz)
        jobs = ((drive, (session, keys, stop)), (hold_gaze, (session, keys, target, stop)),
                (meter.watch_gaze, (stop,)))  # fmt: skip
        threads = [threading.Thread(target=f, args=a, daemon=True) for f, a in jobs]
        for t in threads:
            t.start()
        time.sleep(5.0)  # the gaze turns to the target and the drive gets going
        meter.take()
        t_minute, taken = time.monotonic(), consumed(session, keys)
        labels = {c["pid"]: c["instance"] for c in ready["services"] if c["pid"]}
        labels |= {up.pid: "router (avs up)", os.getpid(): "soak meter"}
        if junk is not None:
            labels[junk.pid] = "garbage"
        ticks0, t_ticks = thread_ticks(labels), time.monotonic()
        ticks_minute = ticks0
        for minute in range(1, args.minutes + 1):
            time.sleep(max(0.0, t_minute + 60 - time.monotonic()))
            took = time.monotonic() - t_minute
            t_minute = time.monotonic()
            counts, errors = meter.take()
            now = consumed(session, keys)
            rate = {name: round((now[name][0] - taken[name][0]) / (now[name][1] - taken[name][1]),
                                1) if name in now and name in taken else float("nan")
                    for name in ("imu", "cmd_head", "control")}  # fmt: skip
            taken = now
            all_errors += errors
            status = supervised(session, keys)
            # the services' processes: as the supervisor says now, else as avs up started them
            pids = [s.pid for s in status.services if s.pid] if status else started
            rss = {pid: rss_mb(pid) or 0.0 for pid in pids}
            if minute == 1:
                rss_start = dict(rss)
            row = {
                "minute": minute,
                "imu_hz": rate["imu"],
                "cmd_head_hz": rate["cmd_head"],
                "control_hz": rate["control"],
                "frames_hz": round(counts.get(keys.rgbd("head_rgbd"), 0) / took, 2),
                "observation_hz": round(counts.get(keys.observation(), 0) / took, 2),
                "scene_updates": counts.get(keys.scene(), 0),
                "gaze_error_deg_p50": round(float(np.percentile(errors, 50)), 3)
                if errors else float("nan"),
                "gaze_error_deg_p99": round(float(np.percentile(errors, 99)), 3)
                if errors else float("nan"),
                "rss_mb": {str(pid): round(v, 1) for pid, v in rss.items()},
                "restarts": sum(s.restarts for s in status.services) if status else -1,
                "token_flaps": len(meter.flaps),
            }  # fmt: skip
            ticks = thread_ticks(labels)  # each process's share of the machine this minute
            row["cpu_percent"] = {
                label: round(sum(t.values()))
                for label, t in cpu_table(ticks_minute, ticks, took).items()
            }
            ticks_minute = ticks
            if args.outside_1khz:
                row["outside_imu_hz"] = round(counts.get(keys.imu(), 0) / took, 1)
                row["outside_cmd_head_hz"] = round(counts.get(keys.cmd_head(), 0) / took, 1)
            rows.append(row)
            print(f"minute {minute}: IMU {row['imu_hz']} Hz, control steps {row['control_hz']} Hz, "
                  f"cmd/head {row['cmd_head_hz']} Hz, "
                  f"frames {row['frames_hz']} Hz, observations {row['observation_hz']} Hz, "
                  f"scene updates {row['scene_updates']}, "
                  f"gaze error p50 {row['gaze_error_deg_p50']}° p99 {row['gaze_error_deg_p99']}°, "
                  f"restarts {row['restarts']}, token flaps {row['token_flaps']}; CPU % "
                  + ", ".join(f"{k} {v}" for k, v in row["cpu_percent"].items()),
                  flush=True)  # fmt: skip
        cpu = cpu_table(ticks0, thread_ticks(labels), time.monotonic() - t_ticks)
        meter.watching_tokens = False
        stop.set()
        final = supervised(session, keys)
        for s in meter.subs:
            s.undeclare()
    stop_garbage.set()
    if junk is not None:
        junk.join(10)
    up.send_signal(signal.SIGINT)
    up.wait(60)
    reference_after = reference_ms()
    growth = [rows[-1]["rss_mb"].get(str(pid), 0.0) - v for pid, v in rss_start.items()]
    summary = {
        "minutes": args.minutes,
        "imu_hz_min": min(r["imu_hz"] for r in rows),
        "cmd_head_hz_min": min(r["cmd_head_hz"] for r in rows),
        "observation_hz_min": min(r["observation_hz"] for r in rows),
        "scene_updates_per_min_min": min(r["scene_updates"] for r in rows),
        "token_flaps": len(meter.flaps),
        # (the last the supervisor told: a loaded router may leave a query unanswered)
        "restarts": sum(s.restarts for s in final.services)
        if final else max((r["restarts"] for r in rows), default=-1),
        "rss_growth_mb": round(max(growth, default=0.0), 1),
        "gaze_error_deg_p99": round(float(np.percentile(all_errors, 99)), 3)
        if all_errors else float("nan"),
        # the machine's speed before and after (perception alone on one frame, CPU ms)
        "reference_perception_ms": max(reference_before, reference_after),
    }  # fmt: skip
    print(f"the machine before and after: perception {reference_before} and "
          f"{reference_after} ms of CPU on one frame alone")  # fmt: skip
    (args.out / "soak.json").write_text(json.dumps({"minutes": rows, "summary": summary,
                                                    "flaps": meter.flaps, "cpu_percent": cpu},
                                                   indent=1))  # fmt: skip
    print("where the cores go (% of one core, the whole run):")
    for label, threads in sorted(cpu.items(), key=lambda kv: -sum(kv[1].values())):
        top = ", ".join(f"{t} {v:.0f}" for t, v in list(threads.items())[:6])
        print(f"  {label}: {sum(threads.values()):.0f} ({top})")
    plot(rows, args.out / "soak.png")
    print(f"wrote {args.out / 'soak.json'} and {args.out / 'soak.png'}")
    print(" ".join(f"{k}={v}" for k, v in summary.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
