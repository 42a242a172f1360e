"""compose.yaml, checked without a docker engine (it validates against the Compose
Specification's JSON Schema and follows our rules: router reachable, same commands as `avs up`,
scalable services without container_name), then run for real: compose.host.yaml's containers
up, scaled, killed and recovered (the live tests at the end; tests/docker_stack.py)."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml
import zenoh

from avs.services import BY_NAME, existing
from schemas import decode
from tests.conftest import ROOT, wait_for

COMPOSE = yaml.safe_load((ROOT / "compose.yaml").read_text())
SCHEMA_PATH = Path(os.environ.get("AVS_VENV", ROOT / ".venv")) / "share/avs/compose_spec.json"


def test_validates_against_the_compose_specification():
    if not SCHEMA_PATH.is_file():
        pytest.fail(f"{SCHEMA_PATH} is missing: run scripts/setup.sh (scripts/test does)")
    schema = json.loads(SCHEMA_PATH.read_text())
    validator = jsonschema.Draft201909Validator(schema)  # the draft its $schema names
    errors = sorted(validator.iter_errors(COMPOSE), key=lambda e: list(e.path))
    assert not errors, "\n".join(f"{list(e.path)}: {e.message}" for e in errors)


def test_the_router():
    """The router reads router-<transport>.json5 from the mounted deploy/zenoh: tcp unless
    AVS_TRANSPORT=tls, the one switch to TLS (services connect to the same scheme)."""
    router = COMPOSE["services"]["router"]
    # eclipse/zenoh where a registry is reachable, else AVS's own (scripts/docker-setup)
    assert router["image"].startswith("${AVS_ROUTER_IMAGE:-eclipse/zenoh:")
    assert "7447:7447/tcp" in router["ports"]
    source, target = router["volumes"][0].split(":")[:2]
    assert (ROOT / source).resolve() == (ROOT / "deploy/zenoh").resolve()
    assert router["command"] == ["-c", f"{target}/router-${{AVS_TRANSPORT:-tcp}}.json5"]
    for transport in ("tcp", "tls"):
        config = zenoh.Config.from_file(str(ROOT / source / f"router-{transport}.json5"))
        assert json.loads(config.get_json("mode")) == "router"
        assert json.loads(config.get_json("listen/endpoints")) == [f"{transport}/[::]:7447"]
        assert json.loads(config.get_json("scouting/multicast/enabled")) is False


def _services() -> dict[str, dict]:
    return {k: v for k, v in COMPOSE["services"].items() if k != "router"}


def test_every_implemented_service_is_deployed_with_the_command_avs_up_runs():
    services = _services()
    assert sorted(services) == sorted(s.name for s in existing())
    for name, service in services.items():
        assert service["command"] == ["python", *BY_NAME[name].argv()], name


def test_every_service_reaches_the_router():
    for name, service in _services().items():
        env = service["environment"]
        assert env["AVS_CONNECT"] == "${AVS_TRANSPORT:-tcp}/router:7447", name
        assert env["AVS_MODE"] == "client" and env["AVS_MULTICAST"] == "false", name
        assert "router" in service["depends_on"], name


def test_every_service_runs_with_the_settings_avs_up_gives_it(monkeypatch):
    """What ``avs up`` hands its services by default (the sensor models, view registration,
    perception's rate) compose.yaml sets too: a deployment runs the system a user tried."""
    import argparse

    from avs.commands.up import service_env

    for key in list(os.environ):
        if key.startswith("AVS_"):
            monkeypatch.delenv(key)
    defaults = argparse.Namespace(noise="on", data_dir="avs-data", scene=None)
    settings = {k: v for k, v in service_env(defaults).items() if not k.endswith("_DATA_DIR")}
    owners = {"AVS_SIM_": "sim", "AVS_PERCEPTION_": "perception",
              "AVS_SCENE_MEMORY_": "scene_memory"}  # fmt: skip
    assert settings and all(any(k.startswith(p) for p in owners) for k in settings), settings
    for key, value in settings.items():
        service = next(name for prefix, name in owners.items() if key.startswith(prefix))
        assert COMPOSE["services"][service]["environment"].get(key) == value, (service, key)


def test_scalable_services_have_no_container_name():
    for name, service in _services().items():
        if BY_NAME[name].scalable:
            assert "container_name" not in service, name


def test_the_service_template_is_what_every_service_uses():
    template = COMPOSE["x-avs-service"]
    assert template["build"] == "."
    assert template["environment"]["AVS_CONNECT"] == "${AVS_TRANSPORT:-tcp}/router:7447"
    assert (ROOT / "Dockerfile").is_file()


def test_the_scene_memory_keeps_its_data_in_a_named_volume():
    service = COMPOSE["services"]["scene_memory"]
    data_dir = service["environment"]["AVS_SCENE_MEMORY_DATA_DIR"]
    named = [v.split(":") for v in service["volumes"] if not v.startswith("./")]
    assert [data_dir] == [target for _, target in named]
    assert {name for name, _ in named} <= set(COMPOSE["volumes"])
    # the image's non-root user owns the mount point, so a new volume is writable
    assert f"install -d -o avs -g avs {data_dir}" in (ROOT / "Dockerfile").read_text()


def test_every_service_logs_in_with_its_own_identity():
    """The router's access control knows a service by its user name (deploy/zenoh/router-*.json5,
    tests/test_acl.py); passwords come from .env (python -m avs.acl --credentials .)."""
    config = zenoh.Config.from_file(str(ROOT / "deploy/zenoh/router-tcp.json5"))
    assert json.loads(config.get_json("access_control/enabled")) is True
    assert json.loads(config.get_json("transport/auth/usrpwd/dictionary_file")) == (
        "/etc/avs/credentials.txt"
    )
    for name, service in _services().items():
        env = service["environment"]
        assert env["AVS_USER"] == name, name
        assert env["AVS_PASSWORD"].startswith(f"${{AVS_PASSWORD_{name.upper()}:?"), name


def test_every_service_has_a_health_check_on_its_liveliness():
    for name, service in _services().items():
        check = service["healthcheck"]
        assert check["test"] == ["CMD", "python", "-m", "services.common.health", name], name
        assert check["interval"] and check["retries"] >= 1


def test_the_health_check_sees_this_hosts_instance(router):
    """services.common.health against a live token named like a default instance
    (<hostname>-<pid>): exit 0 for that service, 1 for another."""
    import socket
    import subprocess
    import sys

    from schemas.keys import Keys
    from tests.conftest import avs_env, session_config

    instance = f"{socket.gethostname()}-4242".replace("/", "-")
    with zenoh.open(session_config("client", connect=[router])) as session:
        token = session.liveliness().declare_token(Keys().alive("perception", instance))

        def check(service: str) -> int:
            return subprocess.run(
                [sys.executable, "-m", "services.common.health", service],
                env=avs_env(router), cwd=ROOT, capture_output=True, timeout=60,
            ).returncode  # fmt: skip

        assert check("perception") == 0
        assert check("nbv") == 1
        token.undeclare()


HOST = yaml.safe_load((ROOT / "compose.host.yaml").read_text())


def test_the_host_network_file_is_compose_yaml_on_loopback():
    """compose.host.yaml's services are compose.yaml's but for the network: on the host's,
    the router on 127.0.0.1 only and every service connecting there (and TCP)."""
    assert HOST["services"]["router"]["command"][-2:] == ["-l", "tcp/127.0.0.1:${AVS_PORT:-7447}"]
    assert HOST["services"]["router"]["image"] == COMPOSE["services"]["router"]["image"]
    for name, service in _services().items():
        host = HOST["services"][name]
        assert host["network_mode"] == "host", name
        assert host["environment"]["AVS_CONNECT"] == "tcp/127.0.0.1:${AVS_PORT:-7447}", name
        same = {
            k: v
            for k, v in service["environment"].items()
            if k not in ("AVS_CONNECT", "AVS_TLS_CA")
        }
        assert {k: host["environment"][k] for k in same} == same, name
        for key in ("command", "healthcheck", "restart", "depends_on"):
            assert host[key] == service[key], (name, key)
        assert host.get("cap_add") == service.get("cap_add"), name
        named = [v for v in service["volumes"] if not v.startswith("./")]
        assert host.get("volumes", []) == named, name


# -- live: the containers themselves (tests/docker_stack.py) -------------------------------------
# scripts/test runs scripts/docker-setup first (as root) and sets AVS_REQUIRE_DOCKER=1 when it
# made the images: then these fail, never skip. One `compose up` serves them all, in this order.


def _require_docker() -> None:
    from tests.docker_stack import docker_missing

    if reason := docker_missing():
        if os.environ.get("AVS_REQUIRE_DOCKER") == "1":
            pytest.fail(f"scripts/docker-setup succeeded, yet {reason}")
        pytest.skip(f"{reason}: run scripts/docker-setup (scripts/test does, as root)")


#: run in the image: the numba cache's files (path, mtime) before and after ``avs warm-up``
_CACHE_UNTOUCHED = """
import os, subprocess, services
def files():
    d = os.environ["NUMBA_CACHE_DIR"]
    return sorted((os.path.join(r, f), os.stat(os.path.join(r, f)).st_mtime_ns)
                  for r, _, fs in os.walk(d) for f in fs)
before = files()
subprocess.run(["avs", "warm-up"], check=True, capture_output=True)
print(len(before), before == files())
"""


def test_live_the_image_holds_every_service_kernel_compiled():
    """The image's build ran ``avs warm-up``: its numba cache holds the kernels every service
    compiles as it starts, so a container starts in seconds (15 s for the whole stack here,
    against 96 s when each compiled its own). Warming up again in a container writes nothing."""
    import subprocess

    _require_docker()
    out = subprocess.run(
        ["docker", "run", "--rm", "avs:latest", "python", "-c", _CACHE_UNTOUCHED],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    files, untouched = out.stdout.split()
    assert int(files) >= 40 and untouched == "True", out.stdout


@pytest.fixture(scope="module")
def stack(tmp_path_factory):
    from tests.docker_stack import Stack

    _require_docker()
    stack = Stack(tmp_path_factory.mktemp("compose"), f"avstest{os.getpid()}")
    stack.t_up = time.monotonic()
    try:
        stack.compose("up", "-d", "--no-build", "--scale", "perception=2")
        yield stack
    finally:
        stack.compose("down", "-v", "--timeout", "5")


@pytest.fixture(scope="module")
def observer(stack):
    from tests.docker_stack import watch

    session = stack.session("observer")
    seen, subs = watch(session)
    yield seen
    for s in subs:
        s.undeclare()
    session.close()


def _seqs(seen) -> list[int]:
    return [seq for _, seq, _ in seen.observations]


@pytest.mark.timeout(300)
def test_live_every_container_turns_healthy(stack):
    services = ["sim", "perception", "perception", "scene_memory", "nbv", "gaze", "explorer"]

    def health() -> dict[str, str]:
        return {c.name: c.attrs["State"].get("Health", {}).get("Status") for c in
                stack.containers() if "Health" in c.attrs["State"]}  # fmt: skip

    wait_for(lambda: list(health().values()).count("healthy") == len(services), 240,
             "every service container healthy", health)  # fmt: skip
    names = sorted(c.labels["com.docker.compose.service"] for c in stack.containers())
    assert names == sorted(["router", *services])
    print(f"all healthy {time.monotonic() - stack.t_up:.0f} s after compose up")


@pytest.mark.timeout(420)
def test_live_the_stack_explores_by_itself_and_only_the_operator_may_stop_it(stack):
    """``docker compose up`` explores: the explorer starts by itself in the roi the sim's scene
    declares; from outside (observer identity: it only reads) the support graph is found
    (F1 ≥ 0.9, ``avs score``'s evaluation) within 240 s of the start. Then the operator starts
    an episode; the observer's stop is refused at the router (the episode goes on), the
    operator's stops it."""
    from avs.commands.score import score
    from schemas import ExploreControl, ExploreStatus, encode
    from tests.docker_stack import KEYS, query

    statuses: list[ExploreStatus] = []
    with stack.session("observer") as observer:
        sub = observer.declare_subscriber(
            KEYS.explore_status(),
            lambda s: statuses.append(decode(s.payload.to_bytes(), ExploreStatus)),
        )
        wait_for(lambda: statuses and statuses[-1].phase == "done", 240 + stack.t_up
                 - time.monotonic(), "the episode's end", lambda: statuses[-1:])  # fmt: skip
        took = time.monotonic() - stack.t_up
        result = score(observer, KEYS, 30.0)
        print(f"explored by itself: {statuses[-1].reason} after {statuses[-1].view} views, "
              f"{took:.0f} s after compose up; support F1 {result['support_f1']:.2f}")  # fmt: skip
        assert statuses[-1].reason in ("quality", "max_views"), statuses[-1]
        assert result["support_f1"] >= 0.9, result
        with stack.session("operator") as operator:
            start = query(operator, KEYS.explore_control(), ExploreStatus,
                          encode(ExploreControl(op="start")))  # fmt: skip
            assert start is not None and start.ok and start.episode == 2, start
            wait_for(lambda: statuses[-1].episode == 2 and statuses[-1].phase != "plan", 120,
                     "the second episode under way")  # fmt: skip
            stop = encode(ExploreControl(op="stop"))
            assert query(observer, KEYS.explore_control(), ExploreStatus, stop) is None
            time.sleep(1)
            assert statuses[-1].episode == 2 and statuses[-1].reason != "stopped"
            stopped = query(operator, KEYS.explore_control(), ExploreStatus, stop)
            assert stopped is not None and (stopped.phase, stopped.reason) == ("done", "stopped")
        sub.undeclare()


@pytest.mark.timeout(120)
def test_live_an_observer_on_the_host_receives_frames_observations_and_the_scene(stack, observer):
    """...and commands nothing: its put on cmd/base never reaches the operator's subscriber."""
    from tests.docker_stack import KEYS

    operator = stack.session("operator")
    commands: list[bytes] = []
    sub = operator.declare_subscriber(KEYS.key("cmd/base"), lambda s: commands.append(s))
    with stack.session("observer") as outsider:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 10:
            outsider.put(KEYS.key("cmd/base"), b"go")
            time.sleep(0.5)
    seen = observer.since(t0)
    counts = (len(seen.frames), len(seen.observations), len(seen.models))
    print(f"the observer in 10 s: frames, observations, scene models = {counts}")
    assert counts[0] >= 20 and counts[1] >= 10 and counts[2] >= 1, counts  # 4 frames/s
    assert commands == []  # denied at the router; the operator's goes through:
    with stack.session("operator") as other:
        other.put(KEYS.key("cmd/base"), b"go")
        wait_for(lambda: len(commands) == 1, 10, "the operator's command")
    sub.undeclare()
    operator.close()


@pytest.mark.timeout(180)
def test_live_two_perception_containers_process_each_frame_exactly_once(stack, observer):
    from services.common.membership import owner

    t0 = time.monotonic()
    time.sleep(12)  # about 40 frames at 4 a second
    frames = sorted({seq for _, seq in observer.since(t0 + 2).frames})  # past what was queued
    wait_for(lambda: set(frames) <= set(_seqs(observer.since(t0))), 30, "their observations")
    seen = observer.since(t0)
    done = [(seq, w) for _, seq, w in seen.observations if frames[0] <= seq <= frames[-1]]
    assert sorted(seq for seq, _ in done) == frames  # each frame, once
    workers = sorted({w for _, w in done})
    per_worker = {w: sum(1 for _, x in done if x == w) for w in workers}
    print(f"{len(frames)} frames in 10 s, processed by {per_worker}")
    assert len(workers) == 2 and min(per_worker.values()) >= len(frames) / 5, per_worker
    assert all(owner(f"head_rgbd:{seq}", workers) == w for seq, w in done)  # by rendezvous


@pytest.mark.timeout(240)
def test_live_scene_memory_crashed_in_its_container_comes_back_with_its_state(stack, observer):
    """kill -9 of the service process (from the host: the kernel ignores SIGKILL to a
    namespace's PID 1 sent from inside); `docker kill` would disable the restart policy."""
    import signal

    from schemas import OccupancyStats, SceneModel, SimControl, SimStatus, encode
    from tests.docker_stack import KEYS, query

    operator = stack.session("operator")
    (memory,) = stack.containers("scene_memory")
    try:
        query(operator, KEYS.sim_control(), SimStatus, encode(SimControl(op="pause")))

        def model():
            return query(operator, KEYS.scene(), SceneModel)

        def quiet() -> bool:  # no update for 3 s: the paused stream drained
            return (last := observer.since(0).models) and time.monotonic() - last[-1][0] > 3

        wait_for(quiet, 60, "the scene memory idle with the sim paused")
        before, stats = model(), query(operator, KEYS.occupancy("stats"), OccupancyStats)
        assert before.model_version > 0 and before.primitives
        restarts = memory.attrs["RestartCount"]
        t_kill = time.monotonic()
        os.kill(memory.attrs["State"]["Pid"], signal.SIGKILL)
        wait_for(lambda: memory.reload() or memory.attrs["RestartCount"] == restarts + 1, 60,
                 "the restart policy")  # fmt: skip
        t_restart = time.monotonic() - t_kill
        wait_for(lambda: (m := model()) is not None and m.model_version >= before.model_version,
                 90, "the scene memory serving again")  # fmt: skip
        t_serving = time.monotonic() - t_kill
        after = model()
        after_stats = query(operator, KEYS.occupancy("stats"), OccupancyStats)
        print(f"scene_memory restarted {t_restart:.1f} s after kill -9, serving after "
              f"{t_serving:.1f} s: version {after.model_version}, "
              f"{len(after.primitives)} primitives")  # fmt: skip
        assert (after.model_version, len(after.primitives)) == (
            before.model_version, len(before.primitives))  # fmt: skip
        # the same frames in the map; the replayed ones since the last snapshot are registered
        # again, and ICP on several threads is not bit-reproducible: the voxel counts agree to
        # within 0.1 % (they did exactly while the robot stood still: no keyframe to replay)
        assert after_stats.frames_integrated == stats.frames_integrated
        now = np.array([after_stats.unknown, after_stats.free, after_stats.occupied])
        then = np.array([stats.unknown, stats.free, stats.occupied])
        assert np.abs(now - then).max() <= 1e-3 * then.sum(), (now, then)
        memory.reload()
        assert memory.attrs["State"]["Status"] == "running" and t_serving < 60
    finally:
        query(operator, KEYS.sim_control(), SimStatus, encode(SimControl(op="resume")))
        operator.close()
    t0 = time.monotonic()
    wait_for(lambda: observer.since(t0).models, 60, "updates fused after the restart")


@pytest.mark.timeout(180)
def test_live_a_killed_perception_container_loses_its_queue_at_most(stack, observer):
    from services.common.membership import owner

    containers = stack.containers("perception")
    t0 = time.monotonic()
    # both at work (run alone, the stack is still starting)
    wait_for(lambda: len({w for _, _, w in observer.since(t0).observations}) == 2, 240,
             "observations from both perception containers")  # fmt: skip
    time.sleep(5)
    workers = sorted({w for _, _, w in observer.since(t0).observations})
    assert len(workers) == 2, workers
    victim = containers[0]
    victim.kill()  # SIGKILL; `docker kill` also keeps the restart policy from bringing it back
    t_kill = time.monotonic()
    time.sleep(15)
    frames = sorted({seq for _, seq in observer.since(t0 + 1, t_kill + 12).frames})
    wait_for(lambda: set(frames[-8:]) <= set(_seqs(observer.since(t0))), 30, "the last frames")
    seen = observer.since(t0)
    done = {seq: w for _, seq, w in seen.observations}
    assert len(done) == len(seen.observations), "a frame processed twice"
    missing = [s for s in frames if s not in done]
    late = frames[-20:]  # the last 5 s: the survivor took every one
    assert all(s in done for s in late), (t_kill - t0, late, sorted(done.items())[-30:])
    killed = {w for w in workers if w not in {done[s] for s in late}}
    assert len(killed) == 1, workers
    (dead,) = killed
    kill_seq = max(s for s, w in done.items() if w == dead)
    # lost: only the dead worker's frames, those it held (a queue of 16) and those sent in the
    # second or two before the survivor saw its token go
    assert all(owner(f"head_rgbd:{s}", workers) == dead for s in missing), missing
    assert all(kill_seq - 16 <= s <= kill_seq + 12 for s in missing), (kill_seq, missing)
    victim.reload()
    assert victim.attrs["State"]["Status"] == "exited"
    print(
        f"killed {dead}: {len(missing)} frames lost {missing}; the survivor took "
        f"{sum(1 for s in frames if s > kill_seq + 12)} after"
    )


@pytest.mark.timeout(120)
def test_live_compose_down_leaves_nothing(stack):
    stack.compose("down", "-v", "--timeout", "5")
    label = {"label": [f"com.docker.compose.project={stack.name}"]}
    assert stack.containers(all=True) == []
    assert stack.docker.volumes.list(filters=label) == []
    assert stack.docker.networks.list(filters=label) == []
