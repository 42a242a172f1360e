"""The ``avs`` command line as a user runs it: every command has --help; echo prints and
survives garbage; up and run start and stop cleanly."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys

import msgpack
import pytest
import zenoh

from avs.cli import build_parser
from schemas import REGISTRY, Keys, ServiceMetrics, decode, encode
from tests.conftest import (
    avs_env,
    free_port,
    matched_publisher,
    session_config,
    wait_for,
)
from tests.streams import imu_sample

AVS = [sys.executable, "-m", "avs.cli"]


def _subcommands(parser) -> list[list[str]]:
    paths = []
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            for name, sub in action.choices.items():
                paths.append([name])
                paths += [[name, *rest] for rest in _subcommands(sub)]
    return paths


@pytest.mark.parametrize("command", [[], *_subcommands(build_parser())], ids=" ".join)
def test_every_command_has_help(command):
    out = subprocess.run([*AVS, *command, "--help"], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert "usage: avs" in out.stdout


def _options(parser, path=()):
    """(command, action) for every argument of every command."""
    for action in parser._actions:
        if action.__class__.__name__ == "_SubParsersAction":
            for name, sub in action.choices.items():
                yield from _options(sub, (*path, name))
        elif action.dest != "help":
            yield " ".join(path), action


def test_every_option_says_what_it_is_and_its_default():
    """Every argument of every command has help; ``avs explore --help`` shows the defaults
    and names the built-in scenes and robots (``_args.SCENES`` and ``ROBOTS`` are the
    simulator's)."""
    from avs.commands._args import ROBOTS, SCENES
    from services.sim.robots import ROBOTS as SIM_ROBOTS
    from services.sim.scene import BUILTIN_SCENES

    options = _options(build_parser())
    silent = [f"{c} {a.option_strings or a.dest}" for c, a in options if not a.help]
    assert not silent, silent
    assert SCENES == BUILTIN_SCENES and set(ROBOTS) == set(SIM_ROBOTS)
    out = subprocess.run([*AVS, "explore", "--help"], capture_output=True, text=True,
                         timeout=60).stdout  # fmt: skip
    flat = " ".join(out.split())
    for shown in ("(default 10)", "(default tabletop_occluded)", "(default utility)",
                  "(default armar6)", "(default 0)", "kitchen, localization", "booth"):  # fmt: skip
        assert shown in flat, (shown, out)


@pytest.mark.parametrize(
    "command",
    [
        ["explore", "--views", "-1"],
        ["compare", "--jobs", "0"],
        ["compare", "--fusion", "pc,xx"],
        ["explore", "--fusion", "pc,sg"],
        ["fuse", "--voxel", "nan"],
        ["run", "--views", "0"],
        ["explore", "--voxel", "fine"],
        ["gaze-experiment", "--exposure", "bright"],
        ["grasp-experiment", "--jobs", "0"],
    ],
    ids=" ".join,
)
def test_an_argument_out_of_range_fails_in_one_line_before_anything_starts(command, tmp_path):
    out = subprocess.run([*AVS, *command, "--out", str(tmp_path / "out")], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and command[1] in lines[0], out.stderr
    assert not (tmp_path / "out").exists()  # nothing started, nothing written


def test_rendering_needs_no_mujoco_gl(tmp_path):
    """Without MUJOCO_GL and without a display, avs picks EGL itself."""
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MUJOCO_GL", "DISPLAY", "PYOPENGL_PLATFORM")
    }
    out = subprocess.run([*AVS, "perceive", "--scene", "tabletop_clutter", "--json"], env=env,
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert json.loads(out.stdout)["inlier_index"] > 0.8


def test_echo_prints_valid_messages_and_counts_invalid_ones(router, client, procs):
    keys = Keys()
    echo = procs.start(
        [*AVS, "echo", "sensors/imu"],
        env=avs_env(router, AVS_INSTANCE="e1"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    publisher = matched_publisher(client, keys.imu(), timeout=30)  # echo is up and listening
    for payload in (b"\xc1", msgpack.packb({"schema": "ImuSample", "version": 0}), b"1234"):
        publisher.put(payload)
    for i in range(5):
        publisher.put(encode(imu_sample(i)))

    def metrics() -> ServiceMetrics:
        (reply,) = [r.ok for r in client.get(keys.metrics("echo", "e1"), timeout=5) if r.ok]
        return decode(reply.payload.to_bytes(), ServiceMetrics)

    wait_for(lambda: metrics().messages_in.get(keys.imu()) == 8, 20, "echo to receive all")
    m = metrics()
    assert sum(m.dropped.values()) == 3 and m.dropped["wrong_version"] == 1
    assert echo.poll() is None  # still running after garbage
    echo.send_signal(signal.SIGINT)
    out, err = echo.communicate(timeout=20)
    assert echo.returncode == 0
    assert "3 payloads on avs/armar6/sensors/imu were not valid messages" in err, err
    assert "wrong_version=1" in err
    lines = [json.loads(line) for line in out.splitlines()]
    assert [line["message"]["seq"] for line in lines] == [0, 1, 2, 3, 4]
    assert lines[0]["key"] == keys.imu()
    assert lines[0]["message"]["schema"] == "ImuSample"
    assert lines[2]["message"]["angular_velocity"] == imu_sample(2).angular_velocity.tolist()


def _publish_until_it_exits(echo, publisher, first: int, at_most: int) -> None:
    """IMU samples ``first``, ``first`` + 1, … every 50 ms until ``echo`` exits (or
    ``at_most`` are sent)."""
    for i in range(first, first + at_most):
        if echo.poll() is not None:
            return
        publisher.put(encode(imu_sample(i)))
        with contextlib.suppress(subprocess.TimeoutExpired):
            echo.wait(0.05)


def test_echo_count_exits_by_itself(router, client, procs):
    keys = Keys()
    echo = procs.start(
        [*AVS, "echo", "avs/armar6/sensors/**", "--count", "2"],
        env=avs_env(router, AVS_INSTANCE="e2"),
        stdout=subprocess.PIPE,
        text=True,
    )
    publisher = matched_publisher(client, keys.imu(), timeout=30)
    _publish_until_it_exits(echo, publisher, first=0, at_most=1000)
    out, _ = echo.communicate(timeout=20)
    assert echo.returncode == 0
    assert len(out.splitlines()) == 2


def test_echo_stops_quietly_when_its_reader_closes_the_pipe(router, client, procs):
    """``avs echo KEY | head -c 100``: once the reader has its 100 bytes and closes the pipe,
    echo exits by itself with status 0, no traceback, no BrokenPipeError warning and no
    "invalid" count (the failed writes were not bad payloads)."""
    keys = Keys()
    echo = procs.start(
        [*AVS, "echo", "sensors/imu"],
        env=avs_env(router, AVS_INSTANCE="e3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    publisher = matched_publisher(client, keys.imu(), timeout=30)
    publisher.put(encode(imu_sample(0)))
    assert len(echo.stdout.read(100)) == 100
    echo.stdout.close()  # what head does
    _publish_until_it_exits(echo, publisher, first=1, at_most=400)
    assert echo.wait(20) == 0
    err = echo.stderr.read().decode()
    assert "Traceback" not in err and "BrokenPipe" not in err and "invalid" not in err, err
    assert "not valid messages" not in err, err


def test_up_runs_a_router_that_clients_reach_and_stops_on_sigint(procs, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = procs.start(
        [*AVS, "up", "--listen", endpoint, "--data-dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        text=True,
    )
    ready = json.loads(up.stdout.readline())
    assert ready["router"] == endpoint
    with zenoh.open(session_config("client", connect=[endpoint])) as session:
        wait_for(lambda: bool(session.info.routers_zid()), 10, "the router")
    up.send_signal(signal.SIGINT)
    assert up.wait(30) == 0


@pytest.mark.timeout(180)
def test_up_scales_a_service_and_status_lists_every_instance(procs, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    up = procs.start(
        [*AVS, "up", "--listen", endpoint, "--data-dir", str(tmp_path),
         "--services", "sim,perception", "--scale", "perception=2"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    ready = json.loads(up.stdout.readline())
    assert sorted(c["instance"] for c in ready["services"]) == [
        "perception-0", "perception-1", "sim-0",
    ]  # fmt: skip
    out = subprocess.run([*AVS, "status", "--json", "--connect", endpoint], capture_output=True,
                         text=True, timeout=60)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [json.loads(line) for line in out.stdout.splitlines()]
    assert sorted((r["service"], r["instance"]) for r in rows) == [
        ("perception", "perception-0"), ("perception", "perception-1"), ("sim", "sim-0"),
    ]  # fmt: skip
    assert all(r["uptime_s"] > 0 for r in rows)
    sim = next(r for r in rows if r["service"] == "sim")
    assert sim["out"] > 100  # it has been publishing IMU samples
    table = subprocess.run([*AVS, "status", "--connect", endpoint], capture_output=True,
                           text=True, timeout=60)  # fmt: skip
    head, *body = table.stdout.splitlines()
    assert head.split() == ["service", "instance", "uptime_s", "in", "out", "dropped"]
    assert len(body) == 3 and all(len(line.split()) == 6 for line in body), table.stdout
    assert "perception-1" in table.stdout and "{" not in table.stdout  # no Python dicts
    up.send_signal(signal.SIGINT)
    assert up.wait(30) == 0


def test_up_refuses_to_scale_a_service_that_does_not_scale(tmp_path):
    out = subprocess.run(
        [*AVS, "up", "--listen", f"tcp/127.0.0.1:{free_port()}", "--data-dir", str(tmp_path),
         "--scale", "sim=2"],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert out.returncode != 0 and "scalable" in out.stderr and "Traceback" not in out.stderr


def test_up_refuses_a_busy_port_with_one_line(router):
    out = subprocess.run(
        [*AVS, "up", "--listen", router], capture_output=True, text=True, timeout=60
    )
    assert out.returncode != 0
    assert "cannot start the Zenoh router" in out.stderr
    assert "Traceback" not in out.stderr


def test_schema_export(tmp_path):
    out = subprocess.run(
        [*AVS, "schema", "export", str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0
    assert sorted(p.stem for p in tmp_path.glob("*.json")) == sorted(REGISTRY)


def test_up_says_where_the_scene_memory_keeps_its_state(tmp_path):
    from avs.commands.up import data_dir_note

    empty = data_dir_note(tmp_path)
    assert str((tmp_path / "scene_memory").resolve()) in empty and "starts empty" in empty
    (tmp_path / "scene_memory").mkdir()
    (tmp_path / "scene_memory" / "journal.bin").write_bytes(b"x")
    held = data_dir_note(tmp_path)
    assert "restores it" in held and "delete the folder" in held
