"""compose.yaml, checked without a docker engine: it validates against the Compose
Specification's JSON Schema, and follows our rules (router reachable, same commands as
`avs up`, scalable services without container_name)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import jsonschema
import pytest
import yaml
import zenoh

from avs.services import BY_NAME, existing
from tests.conftest import ROOT

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
    assert router["image"].startswith("eclipse/zenoh:")
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
