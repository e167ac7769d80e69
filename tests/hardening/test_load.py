"""Eight clients at once against one server: one owns it, the others get ``BusyError``.

The ownership policy (protocol/README.md, "Ownership"): the session whose ``configure``
succeeded owns the arena; every other session gets ``busy`` for arena requests and for
``configure`` until the owner closes or stays silent for ``--lease`` seconds. These tests
check that under contention no foreign request reaches the owner's episode (its trajectory
equals an undisturbed in-process one, bit for bit) and that the lease hands the server over.
"""

from __future__ import annotations

import threading
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import RM
from neuronsmae.protocol.errors import BusyError
from neuronsmae.protocol.messages import (
    Configure,
    ErrorReply,
    Get,
    Message,
    OkReply,
    Ping,
    Render,
    Reset,
    Step,
    encode_request,
)
from neuronsmae.server.arena import Arena

from .conftest import RawClient, Server, same

CLIENTS = 8
LEASE_S = 3.0


@pytest.fixture(scope="module")
def server(start_server: Callable[..., Server]) -> Server:
    return start_server("--lease", str(LEASE_S))


def _claim(port: int, barrier: threading.Barrier) -> RM | BusyError:
    barrier.wait()
    try:
        return RM(seed=3, port=port, launch=False, timeout=10.0)
    except BusyError as exc:
        return exc


def _allowed(arena: Arena, rng: np.random.Generator) -> list[int]:
    return [int(rng.choice(np.flatnonzero(m))) for m in arena.get_avail_actions()]


HAMMER: list[Message] = [
    Configure(seed=99),
    Reset(),
    Step(actions=[0, 0]),
    Get(what="obs"),
    Render(),
    Ping(),
]


def _hammer(port: int, session: str, stop: threading.Event, out: Counter[str]) -> None:
    """Another client that keeps trying every request while the owner plays."""
    raw = RawClient(port)
    try:
        k = 0
        while not stop.is_set() and k < 2000:
            body = HAMMER[k % len(HAMMER)]
            reply = raw.send(encode_request(body, session), timeout=5.0)
            kind = type(body).__name__
            if isinstance(reply, ErrorReply):
                out[f"{kind}:{reply.code}"] += 1
            elif isinstance(reply, OkReply):
                out[f"{kind}:ok"] += 1
            else:
                out[f"{kind}:no-reply"] += 1
            k += 1
    finally:
        raw.close()


def test_eight_clients_one_owner_and_an_undisturbed_episode(server: Server) -> None:
    barrier = threading.Barrier(CLIENTS)
    with ThreadPoolExecutor(CLIENTS) as pool:
        results = list(pool.map(lambda _: _claim(server.port, barrier), range(CLIENTS)))
    owners = [r for r in results if isinstance(r, RM)]
    refused = [r for r in results if isinstance(r, BusyError)]
    assert len(owners) == 1 and len(refused) == CLIENTS - 1
    assert all("owned by another client" in str(e) for e in refused)

    owner, local = owners[0], Arena(seed=3)
    tallies: list[Counter[str]] = [Counter() for _ in range(CLIENTS - 1)]
    stop = threading.Event()
    others = [
        threading.Thread(target=_hammer, args=(server.port, f"other-{i}", stop, tallies[i]))
        for i in range(CLIENTS - 1)
    ]
    try:
        for t in others:
            t.start()
        rng = np.random.default_rng(3)
        assert same(owner.reset(), local.reset())
        for k in range(1000):  # at least 60 decisions, and until every other had a round
            actions = _allowed(local, rng)
            assert same(owner.step(actions), local.step(actions))
            assert same(owner.get_state(), local.get_state())
            if local.done:
                assert same(owner.reset(), local.reset())
            if k >= 60 and min(sum(t.values()) for t in tallies) >= len(HAMMER):
                break
    finally:
        stop.set()
        for t in others:
            t.join(30)
        owner.close()
        local.close()
    tally = sum(tallies, Counter())
    assert min(sum(t.values()) for t in tallies) >= len(HAMMER)
    assert {k for k in tally if not k.endswith(":busy")} == {"Ping:ok"}, tally


def test_a_silent_owner_loses_the_server_after_its_lease(server: Server) -> None:
    first = RM(seed=4, port=server.port, launch=False, timeout=5.0)
    try:
        first.reset()
        with pytest.raises(BusyError):
            RM(seed=5, port=server.port, launch=False)
        time.sleep(LEASE_S + 0.5)  # the owner says nothing for longer than its lease
        with RM(seed=5, port=server.port, launch=False, timeout=5.0) as second:
            with pytest.raises(BusyError):
                first.step([0, 0])  # the former owner is now the outsider
            local = Arena(seed=5)
            assert same(second.reset(), local.reset())  # a fresh arena, not first's
            actions: Any = _allowed(local, np.random.default_rng(5))
            assert same(second.step(actions), local.step(actions))
            local.close()
    finally:
        first.close()
