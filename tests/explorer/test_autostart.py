"""The explorer's autostart (``AVS_EXPLORER_AUTOSTART``, as compose and ``avs up`` run it): the
episode waits for the services it needs, so a scene memory that takes a minute to start on a
loaded machine does not end it at its first view ("frame N never reached the scene model")."""

from __future__ import annotations

import threading
import time

import pytest

from schemas import ExploreStatus, Keys, decode
from tests.conftest import avs_env, liveliness_tokens, wait_for

KEYS = Keys()


@pytest.mark.timeout(120)
def test_an_autostarted_episode_waits_until_the_services_it_needs_are_alive(router, client, procs):
    statuses: list[ExploreStatus] = []
    lock = threading.Lock()

    def on_status(sample) -> None:
        with lock:
            statuses.append(decode(sample.payload.to_bytes(), ExploreStatus))

    client.declare_subscriber(KEYS.explore_status(), on_status)
    explorer = procs.python(
        ["-m", "services.explorer", "--roi-min", "0,0,0", "--roi-max", "1,1,1"],
        env=avs_env(router, AVS_EXPLORER_AUTOSTART="true"),
    )  # fmt: skip
    wait_for(lambda: explorer.poll() is not None
             or any(t.startswith(KEYS.key("alive/explorer/")) for t in liveliness_tokens(client,
                    KEYS.alive())), 60, "the explorer's token")  # fmt: skip
    assert explorer.poll() is None, "the explorer exited"
    # two of the three announce themselves: the episode does not start
    tokens = [client.liveliness().declare_token(KEYS.alive(s, "stand-in")) for s in ("nbv",
              "perception")]  # fmt: skip
    time.sleep(3.0)
    with lock:
        assert not statuses, statuses[-1]
    assert explorer.poll() is None
    # the scene memory comes up last: the episode starts, its first phase planning
    tokens.append(client.liveliness().declare_token(KEYS.alive("scene_memory", "stand-in")))
    wait_for(lambda: bool(statuses), 10, "the episode's first status")
    with lock:
        assert statuses[0].episode == 1 and statuses[0].phase == "plan", statuses[0]
    for t in tokens:
        t.undeclare()
