"""An exploration episode across hosts, without docker: Linux network namespaces as the hosts,
each with a veth pair onto one bridge. The router (in the orchestrator, the bridge's address
10.77.0.1) and every service in a namespace of its own, connecting to the router over TCP
through the bridge. Skipped, with the reason, where namespaces cannot be made (not root, no
`ip`, a container without CAP_NET_ADMIN)."""

from __future__ import annotations

import os
import shutil
import subprocess
import threading

import pytest

from experiments.episode import EPISODE_SERVICES, Episode, EpisodeConfig

BRIDGE, NET = "avsbr0", "10.77.0"


def ip(*args: str, ns: str | None = None) -> None:
    cmd = ["ip", "netns", "exec", ns, "ip", *args] if ns else ["ip", *args]
    subprocess.run(cmd, check=True, capture_output=True, text=True)


def _can_make_namespaces() -> str:
    if shutil.which("ip") is None:
        return "no `ip` command (iproute2)"
    if os.geteuid() != 0:
        return "network namespaces need root"
    probe = subprocess.run(["ip", "netns", "add", "avs-probe"], capture_output=True, text=True)
    if probe.returncode != 0:
        return f"cannot create a network namespace: {probe.stderr.strip()}"
    subprocess.run(["ip", "netns", "del", "avs-probe"], capture_output=True)
    return ""


@pytest.fixture
def hosts():
    """One namespace per episode service on a bridge; yields {service: namespace}."""
    reason = _can_make_namespaces()
    if reason:
        pytest.skip(reason)
    made: dict[str, str] = {}
    try:
        ip("link", "add", BRIDGE, "type", "bridge")
        ip("addr", "add", f"{NET}.1/24", "dev", BRIDGE)
        ip("link", "set", BRIDGE, "up")
        for i, service in enumerate(EPISODE_SERVICES):
            ns, host_end, ns_end = f"avs-host-{service}", f"avsv{i}h", f"avsv{i}n"
            subprocess.run(["ip", "netns", "add", ns], check=True, capture_output=True)
            made[service] = ns
            ip("link", "add", host_end, "type", "veth", "peer", "name", ns_end)
            ip("link", "set", host_end, "master", BRIDGE)
            ip("link", "set", host_end, "up")
            ip("link", "set", ns_end, "netns", ns)
            ip("addr", "add", f"{NET}.{10 + i}/24", "dev", ns_end, ns=ns)
            ip("link", "set", ns_end, "up", ns=ns)
            ip("link", "set", "lo", "up", ns=ns)
            ping = subprocess.run(["ip", "netns", "exec", ns, "ping", "-c", "1", "-W", "2",
                                   f"{NET}.1"], capture_output=True, text=True)  # fmt: skip
            if ping.returncode != 0 and shutil.which("ping"):
                pytest.fail(f"{ns} cannot reach the bridge: {ping.stdout}{ping.stderr}")
        yield made
    finally:
        for ns in made.values():
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        subprocess.run(["ip", "link", "del", BRIDGE], capture_output=True)


@pytest.mark.timeout(600)
def test_an_episode_runs_with_every_service_on_its_own_host(hosts, tmp_path):
    seen: dict[str, bool] = dict.fromkeys(hosts.values(), False)
    done = threading.Event()

    def watch() -> None:  # each namespace holds a process of its service while it runs
        while not done.wait(0.5):
            for ns in seen:
                pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True)
                seen[ns] |= bool(pids.stdout.split())

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    config = EpisodeConfig(
        scene="tabletop_occluded", views=2, voxel=0.02, out=tmp_path, host=f"{NET}.1",
        launch={s: ["ip", "netns", "exec", ns] for s, ns in hosts.items()},
    )  # fmt: skip
    result = Episode(config).run().to_json()
    done.set()
    watcher.join(5)
    assert all(seen.values()), seen
    views = result["views"]
    assert len(views) == 2 and views[-1]["support_f1"] >= 0.8, views
    assert views[1]["unknown_voxels"] < views[0]["unknown_voxels"]
