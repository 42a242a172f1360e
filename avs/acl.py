"""Zenoh access control of an AVS deployment, derived from the key table (SPEC §1) so the two
cannot drift: each service may publish only the keys it produces, serve only its queryables and
declare only its own liveliness token; the ``observer`` identity may subscribe to everything,
query what only reads (metrics, scene memory, ground truth) and publish nothing; the
``operator`` identity (the command line and the episode driver: up, explore, echo…) may do
anything under ``avs/``, and it alone may query ``sim/control`` and ``explore/control`` (a
service may ask any other queryable, never to step, reset or pause the sim, nor to start or
stop an exploration).

``python -m avs.acl deploy/zenoh`` writes the router configurations compose.yaml mounts,
``router-tcp.json5`` and ``router-tls.json5`` (``tests/test_acl.py`` checks the shipped ones are
what this makes);
``python -m avs.acl --credentials .`` writes random passwords for every identity:
``deploy/zenoh/credentials.txt`` for the router and ``.env`` for compose (both git-ignored)."""

from __future__ import annotations

import argparse
import json
import secrets
import subprocess
import sys
from pathlib import Path

from avs.services import SERVICES
from schemas.keys import KEY_TABLE

ANY = "avs/*/"  # every robot
#: keys a service produces beyond the table's producer column
EXTRA_PUBLISHES = {
    "nbv": ["cmd/head"],  # the head joints of a chosen view (nbv/plan execute)
    "explorer": ["cmd/base", "gaze/target"],  # a halt; the view's target for the gaze to hold
}
#: what the observer may query: queryables that only read
READ_ONLY = ["metrics/**", "memory/**", "sim/ground_truth"]
OBSERVER, OPERATOR = "observer", "operator"
#: queryables only the operator may ask
OPERATOR_ONLY = ["sim/control", "explore/control"]


def _keys(patterns: list[str]) -> list[str]:
    return [ANY + p for p in patterns]


def produced(service: str) -> tuple[list[str], list[str]]:
    """(keys the service publishes, keys it serves) by the key table."""
    put = [
        k.pattern for k in KEY_TABLE if k.producer == service and k.kind in ("stream", "command")
    ]
    put += EXTRA_PUBLISHES.get(service, [])
    serve = [k.pattern for k in KEY_TABLE if k.producer == service]  # streams answer queries too
    return put, [*serve, f"metrics/{service}/**"]


def _rule(rid: str, flows: list[str], messages: list[str], keys: list[str]) -> dict:
    return {"id": rid, "permission": "allow", "flows": flows, "messages": messages,
            "key_exprs": keys}  # fmt: skip


def access_control() -> dict:
    """The ``access_control`` block (default deny)."""
    services = [s.name for s in SERVICES]
    everything = ["avs/**"]
    rules = [
        # what any identity may receive and look at
        # (declarations go out too: a publisher sends only where it knows of a subscriber)
        _rule("receive", ["egress"], ["put", "delete", "query", "reply", "liveliness_token",
                                      "declare_subscriber", "declare_queryable"], everything),
        _rule("watch", ["ingress"], ["declare_subscriber", "declare_liveliness_subscriber",
                                     "liveliness_query"], everything),
        _rule("ask", ["ingress"], ["query"],
              _keys([k.pattern for k in KEY_TABLE if k.pattern not in OPERATOR_ONLY])),
        _rule("answer", ["ingress"], ["reply"], everything),
        _rule("read", ["ingress"], ["query"], _keys(READ_ONLY)),
        _rule("operate", ["ingress", "egress"],
              ["put", "delete", "query", "reply", "declare_subscriber", "declare_queryable",
               "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
              everything),
    ]  # fmt: skip
    subjects = [
        {"id": OBSERVER, "usernames": [OBSERVER]},
        {"id": OPERATOR, "usernames": [OPERATOR]},
    ]
    policies = [
        {"id": "observer", "rules": ["receive", "watch", "read"], "subjects": [OBSERVER]},
        {"id": "operator", "rules": ["operate"], "subjects": [OPERATOR]},
    ]
    for name in services:
        put, serve = produced(name)
        own = [f"publish-{name}", f"serve-{name}", f"alive-{name}"]
        rules += [
            _rule(own[0], ["ingress"], ["put", "delete"], _keys(put)),
            _rule(own[1], ["ingress"], ["declare_queryable"], _keys(serve)),
            _rule(
                own[2],
                ["ingress"],
                ["liveliness_token"],
                _keys([f"alive/{name}/**", f"alive/{name}_standby/**"]),
            ),
        ]
        subjects.append({"id": name, "usernames": [name]})
        policies.append({"id": name, "rules": ["receive", "watch", "ask", "answer", *own],
                         "subjects": [name]})  # fmt: skip
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}  # fmt: skip


HEADER = """\
// The Zenoh router of an AVS deployment (compose.yaml mounts this file into the router).
// Services connect to it as clients on tcp/router:7447; multicast scouting is off because
// docker networks do not carry it and explicit endpoints are easier to reason about.
// Every client authenticates with a user name and password (credentials.txt, written by
// `python -m avs.acl --credentials .`); access control below lets each identity do only
// what its service does. GENERATED by `python -m avs.acl deploy/zenoh` from the key table
// (schemas/keys.py): edit that, not this. TLS: see deploy/zenoh/README.md.
"""


TLS_DIR = "/etc/avs/tls"


def router_config(transport: str = "tcp") -> dict:
    """The router's configuration; ``transport`` "tls" listens on tls/…:7447 with the
    certificates under /etc/avs/tls (``python -m avs.acl --tls-certs .`` makes them)."""
    tls = {"tls": {"listen_private_key": f"{TLS_DIR}/router.key",
                   "listen_certificate": f"{TLS_DIR}/router.crt",
                   "root_ca_certificate": f"{TLS_DIR}/ca.crt"}}  # fmt: skip
    return {
        "mode": "router",
        "listen": {"endpoints": [f"{transport}/[::]:7447"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {
            "auth": {"usrpwd": {"dictionary_file": "/etc/avs/credentials.txt"}},
            # deeper queues for the urgent priorities: a 2 MB camera frame must not crowd out
            # the 1 kHz IMU and joint streams (services/common/transport.py)
            "link": (tls if transport == "tls" else {}) | {"tx": {"queue": {
                "size": {"real_time": 16, "interactive_high": 16, "interactive_low": 4,
                         "data": 4},
                "congestion_control": {"drop": {"wait_before_drop": 5000}},
            }}},
        },
        "access_control": access_control(),
    }  # fmt: skip


def render(transport: str = "tcp") -> str:
    return HEADER + json.dumps(router_config(transport), indent=2) + "\n"


def write_tls_certificates(root: Path) -> Path:
    """A self-signed CA and a router certificate it signs (for the names router and
    localhost), under deploy/zenoh/tls: what the tls router and its clients load."""
    out = root / "deploy" / "zenoh" / "tls"
    out.mkdir(parents=True, exist_ok=True)

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=out, check=True, capture_output=True)

    openssl(
        "req",
        "-x509",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-days",
        "825",
        "-subj",
        "/CN=AVS CA",
        "-keyout",
        "ca.key",
        "-out",
        "ca.crt",
    )
    openssl(
        "req",
        "-newkey",
        "rsa:2048",
        "-nodes",
        "-subj",
        "/CN=router",
        "-keyout",
        "router.key",
        "-out",
        "router.csr",
    )
    (out / "san.ext").write_text("subjectAltName=DNS:router,DNS:localhost,IP:127.0.0.1\n")
    openssl(
        "x509",
        "-req",
        "-in",
        "router.csr",
        "-CA",
        "ca.crt",
        "-CAkey",
        "ca.key",
        "-CAcreateserial",
        "-days",
        "825",
        "-extfile",
        "san.ext",
        "-out",
        "router.crt",
    )
    for f in ("ca.key", "router.key"):
        (out / f).chmod(0o600)
    return out  # fmt: skip


def identities() -> list[str]:
    return [OBSERVER, OPERATOR, *(s.name for s in SERVICES)]


def write_credentials(root: Path) -> tuple[Path, Path]:
    """Random passwords for every identity: the router's dictionary and compose's .env (in the
    directory of compose.yaml, ``root``)."""
    passwords = {u: secrets.token_urlsafe(18) for u in identities()}
    dictionary = root / "deploy" / "zenoh" / "credentials.txt"
    dictionary.write_text("".join(f"{u}:{p}\n" for u, p in passwords.items()))
    env = root / ".env"
    env.write_text("".join(f"AVS_PASSWORD_{u.upper()}={p}\n" for u, p in passwords.items()))
    for f in (dictionary, env):
        f.chmod(0o600)
    return dictionary, env


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("path", type=Path, help="directory to write router-tcp.json5 and "
                   "router-tls.json5 to, or with --credentials / --tls-certs the directory of "
                   "compose.yaml")  # fmt: skip
    p.add_argument("--credentials", action="store_true", help="random passwords")
    p.add_argument("--tls-certs", action="store_true", help="a CA and the router's certificate")
    args = p.parse_args(argv)
    written = []
    if args.credentials:
        written += write_credentials(args.path)
    if args.tls_certs:
        written.append(write_tls_certificates(args.path))
    if not (args.credentials or args.tls_certs):
        for transport in ("tcp", "tls"):
            path = args.path / f"router-{transport}.json5"
            path.write_text(render(transport))
            written.append(path)
    for f in written:
        print(f"wrote {f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
