"""A server killed in the middle of a request: a clear typed error, then a clean restart.

The client must raise ``ServerUnavailableError`` well within its timeout (Zenoh ends a
query at once when the server's connection drops), lose at most the episode in flight
(the retried request says ``ResetNeededError``), and play a new episode on the restarted
server exactly like a fresh in-process arena. Killing a server between episodes is in
tests/client/test_e2e.py; the measured times are bench/faults.py's.
"""

from __future__ import annotations

import signal
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import RM
from neuronsmae.protocol.errors import ResetNeededError, ServerUnavailableError
from neuronsmae.server.arena import Arena

from .conftest import Server, free_port, same

TIMEOUT = 5.0
TIME_SCALE = 1.0
"""Real time: a paced decision lasts decision_steps × 0.02 s (0.4 s), long enough to kill in."""


def _in_thread(call: Callable[[], Any]) -> tuple[threading.Thread, dict[str, Any]]:
    """Run ``call`` in a thread; the outcome lands in the dict (``error``, ``at``)."""
    out: dict[str, Any] = {}

    def run() -> None:
        try:
            out["value"] = call()
        except Exception as exc:  # the test inspects what was raised
            out["error"] = exc
        out["at"] = time.monotonic()

    thread = threading.Thread(target=run)
    thread.start()
    return thread, out


def _recovers(env: RM, seed: int) -> None:
    """The episode in flight is gone; a new one equals a fresh arena's."""
    deadline = time.monotonic() + 30
    while True:
        try:
            with pytest.raises(ResetNeededError):
                env.step([0, 0])
            break
        except ServerUnavailableError:
            assert time.monotonic() < deadline, "the client never reached the new server"
            time.sleep(0.2)
    local = Arena(seed=seed)
    assert same(env.reset(), local.reset())
    actions = [int(np.flatnonzero(m)[0]) for m in local.get_avail_actions()]
    assert same(env.step(actions), local.step(actions))
    local.close()


def test_server_killed_mid_step_then_mid_reset(start_server: Callable[..., Server]) -> None:
    """Mid-step: killed while it paces the step. Mid-reset: killed with the reset request
    delivered but unanswered (the process was frozen first, so the timing is certain)."""
    port = free_port()
    server = start_server("--time-scale", str(TIME_SCALE), port=port)
    env = RM(seed=6, port=port, launch=False, timeout=TIMEOUT)
    try:
        env.reset()
        env.step([0, 0])  # the pacer's clock starts: the next step waits a whole period
        period = env.get_env_info()["decision_steps"] * 0.02 / TIME_SCALE
        thread, out = _in_thread(lambda: env.step([0, 0]))
        time.sleep(period / 2)  # the server is now inside the step request
        killed = time.monotonic()
        server.proc.kill()
        thread.join(TIMEOUT + 5)
        assert isinstance(out.get("error"), ServerUnavailableError), out
        assert out["at"] - killed < TIMEOUT / 2  # noticed, not waited out

        server = start_server("--time-scale", str(TIME_SCALE), port=port)
        _recovers(env, seed=6)

        server.proc.send_signal(signal.SIGSTOP)  # frozen: the reset request waits unanswered
        thread, out = _in_thread(lambda: env.reset())
        time.sleep(0.3)
        killed = time.monotonic()
        server.proc.kill()
        thread.join(TIMEOUT + 5)
        assert isinstance(out.get("error"), ServerUnavailableError), out
        assert out["at"] - killed < TIMEOUT / 2  # noticed, not waited out

        with pytest.raises(ServerUnavailableError):  # and at once while none is back
            env.reset()
    finally:
        env.close()
