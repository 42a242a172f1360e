"""The router's access control and authentication, with real Zenoh sessions on loopback: the
shipped deploy/zenoh/router-tcp.json5 (what avs/acl.py makes from the key table) lets each
identity do what its service does and no more; the observer watches everything and
publishes nothing; a wrong password does not get in; router-tls.json5 takes the same over
TLS."""

from __future__ import annotations

import json
import shutil
import threading
import time

import pytest
import zenoh

from avs import acl
from avs.services import SERVICES
from schemas import Keys, ServiceMetrics, SimControl, SimStatus, decode, encode
from tests.conftest import ROOT, avs_env, free_port, liveliness_tokens, wait_for

ROUTER = ROOT / "deploy" / "zenoh" / "router-tcp.json5"
PASSWORDS = {u: f"pw-{u}" for u in acl.identities()}


def test_the_shipped_router_configs_are_what_the_key_table_makes():
    for transport in ("tcp", "tls"):
        shipped = (ROUTER.parent / f"router-{transport}.json5").read_text()
        assert shipped == acl.render(transport), "run: python -m avs.acl deploy/zenoh"
    put, serve = acl.produced("sim")
    assert "sensors/imu" in put and "cmd/head" not in put and "sim/control" in serve
    assert "cmd/head" in acl.produced("gaze")[0] and "cmd/head" in acl.produced("nbv")[0]


@pytest.fixture
def secured(tmp_path):
    """A router from the shipped config on a free port, with test credentials."""
    creds = tmp_path / "credentials.txt"
    creds.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    config = zenoh.Config.from_file(str(ROUTER))
    port = free_port()
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(creds)))
    sessions = [zenoh.open(config)]

    def connect(user: str | None, password: str | None = None) -> zenoh.Session:
        c = zenoh.Config()
        c.insert_json5("mode", '"client"')
        c.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
        c.insert_json5("scouting/multicast/enabled", "false")
        if user is not None:
            auth = {"user": user, "password": password or PASSWORDS[user]}
            c.insert_json5("transport/auth/usrpwd", json.dumps(auth))
        s = zenoh.open(c)
        sessions.append(s)
        return s

    connect.endpoint = f"tcp/127.0.0.1:{port}"
    yield connect
    for s in reversed(sessions):
        s.close()


def test_observer_watches_everything_and_commands_nothing(secured):
    probe, observer = secured("operator"), secured("observer")
    sim, gaze = secured("sim"), secured("gaze")
    seen: dict[str, list[tuple[str, bytes]]] = {"probe": [], "observer": []}
    lock = threading.Lock()

    def keep(who):
        def on(sample):
            with lock:
                seen[who].append((str(sample.key_expr), sample.payload.to_bytes()))

        return on

    subs = [probe.declare_subscriber("avs/**", keep("probe")),
            observer.declare_subscriber("avs/**", keep("observer"))]  # fmt: skip
    time.sleep(0.5)
    sim.put("avs/armar6/sensors/imu", b"imu from sim")
    observer.put("avs/armar6/cmd/head", b"head from observer")
    sim.put("avs/armar6/cmd/head", b"head from sim")
    gaze.put("avs/armar6/cmd/head", b"head from gaze")
    gaze.put("avs/armar6/sensors/imu", b"imu from gaze")
    time.sleep(1.0)
    with lock:
        probe_got = {p for _, p in seen["probe"]}
        observer_got = {p for _, p in seen["observer"]}
    assert probe_got == {b"imu from sim", b"head from gaze"}, probe_got  # each its own keys
    assert {b"imu from sim", b"head from gaze"} <= observer_got  # the observer sees it all
    for s in subs:
        s.undeclare()


def test_only_the_operator_controls_the_sim_and_the_observer_only_reads(secured):
    """sim/control (step, reset, pause) answers the operator alone: every service identity and
    the observer are refused; the observer may still read metrics."""
    sim = secured("sim")
    served = [
        sim.declare_queryable(key, lambda q, a=answer: q.reply(q.key_expr, a))
        for key, answer in (("avs/armar6/sim/control", b"ok"), ("avs/armar6/metrics/sim/s1", b"m"))
    ]
    time.sleep(0.5)

    def ask(session, key):
        return [r.ok.payload.to_bytes() for r in session.get(key, timeout=2) if r.ok]

    assert ask(secured("operator"), "avs/armar6/sim/control") == [b"ok"]
    refused = [who for who in acl.identities() if who != "operator"]
    assert set(refused) == {"observer", *(s.name for s in SERVICES)}
    for who in refused:
        assert ask(secured(who), "avs/armar6/sim/control") == [], who
    observer = secured("observer")
    assert ask(observer, "avs/armar6/metrics/sim/s1") == [b"m"]  # reading: allowed
    assert ask(secured("nbv"), "avs/armar6/metrics/sim/s1") == [b"m"]  # services ask the rest
    for q in served:
        q.undeclare()


def test_a_wrong_password_or_an_unknown_user_does_not_get_in(secured):
    with pytest.raises(zenoh.ZError):
        secured("observer", "guess")
    with pytest.raises(zenoh.ZError):
        secured("mallory", "pw-mallory")
    with pytest.raises(zenoh.ZError):  # no credentials at all
        secured(None)


@pytest.mark.timeout(120)
def test_a_service_process_works_behind_the_secured_router(secured, procs):
    """The sim as a process with its identity: its liveliness token, queryables and streams
    pass the router's rules (what the node shell declares is what the ACL allows)."""
    observer, operator = secured("observer"), secured("operator")
    env = avs_env(secured.endpoint, MUJOCO_GL="egl", AVS_USER="sim", AVS_PASSWORD=PASSWORDS["sim"])
    procs.python(["-m", "services.sim", "--instance", "sim-acl", "--fps", "0"], env=env)
    alive = Keys().alive("sim", "sim-acl")
    wait_for(lambda: alive in liveliness_tokens(observer, Keys().alive()), 60, "the sim's token")
    imu: list[bytes] = []
    sub = observer.declare_subscriber(Keys().imu(), lambda s: imu.append(s.payload.to_bytes()))
    wait_for(lambda: len(imu) > 100, 10, "IMU samples at the observer")
    request = encode(SimControl(op="status"))
    status = [r.ok for r in operator.get(Keys().sim_control(), payload=request, timeout=10) if r.ok]
    assert decode(status[0].payload.to_bytes(), SimStatus).ok
    metrics = [r.ok for r in observer.get(Keys().metrics("sim", "sim-acl"), timeout=5) if r.ok]
    assert decode(metrics[0].payload.to_bytes(), ServiceMetrics).service == "sim"
    sub.undeclare()


@pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
def test_the_tls_router_takes_clients_that_trust_its_ca(tmp_path):
    """python -m avs.acl --tls-certs makes a CA and the router's certificate; over tls/ a
    client with the CA (AVS_TLS_CA) and its credentials gets in and its data flows; one
    without the CA does not."""
    from services.common.config import ServiceSettings
    from services.common.transport import zenoh_config

    tls = acl.write_tls_certificates(tmp_path)
    creds = tmp_path / "credentials.txt"
    creds.write_text("".join(f"{u}:{p}\n" for u, p in PASSWORDS.items()))
    config = zenoh.Config.from_file(str(ROUTER.parent / "router-tls.json5"))
    port = free_port()
    config.insert_json5("listen/endpoints", json.dumps([f"tls/127.0.0.1:{port}"]))
    config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(creds)))
    for key, name in (("listen_private_key", "router.key"), ("listen_certificate", "router.crt"),
                      ("root_ca_certificate", "ca.crt")):  # fmt: skip
        config.insert_json5(f"transport/link/tls/{key}", json.dumps(str(tls / name)))
    router = zenoh.open(config)

    def client(user: str, ca: bool) -> zenoh.Session:
        settings = ServiceSettings(
            mode="client", connect=[f"tls/localhost:{port}"], multicast=False, user=user,
            password=PASSWORDS[user], tls_ca=tls / "ca.crt" if ca else None,
        )  # fmt: skip
        return zenoh.open(zenoh_config(settings))

    observer, sim = client("observer", True), client("sim", True)
    got: list[bytes] = []
    sub = observer.declare_subscriber("avs/**", lambda s: got.append(s.payload.to_bytes()))
    time.sleep(0.5)
    sim.put("avs/armar6/sensors/imu", b"imu over tls")
    wait_for(lambda: got == [b"imu over tls"], 5, "the sample over TLS")
    with pytest.raises(zenoh.ZError):
        client("observer", False)  # does not trust the router's certificate
    sub.undeclare()
    for s in (sim, observer, router):
        s.close()
