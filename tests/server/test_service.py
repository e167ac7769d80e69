"""The arena service without a network: ownership, rebuild rules, pacing, refusals."""

from __future__ import annotations

from collections.abc import Iterator
from typing import ClassVar

import msgpack
import numpy as np
import pytest

from neuronsmae.protocol.errors import ERRORS
from neuronsmae.protocol.messages import (
    NOT_CONFIGURED,
    Close,
    Configure,
    Contexts,
    ErrorReply,
    Get,
    Message,
    OkReply,
    Ping,
    Reply,
    Reset,
    Step,
    VReset,
    decode_reply,
    encode_request,
)
from neuronsmae.server.arena import Arena
from neuronsmae.server.contexts import context_table
from neuronsmae.server.serving.service import ArenaService, Pacer


class Clock:
    """A settable monotonic clock, so lease expiry is tested without sleeping."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def clock() -> Clock:
    return Clock()


@pytest.fixture(scope="module")
def service(clock: Clock) -> Iterator[ArenaService]:
    with ArenaService(Arena, seed=5, lease_s=10.0, context_table=context_table, clock=clock) as svc:
        yield svc


def call(service: ArenaService, body: Message, session: str) -> Reply:
    return decode_reply(service.handle(encode_request(body, session)))


def value(service: ArenaService, body: Message, session: str) -> object:
    reply = call(service, body, session)
    assert isinstance(reply, OkReply), reply
    return reply.value


def code(service: ArenaService, body: Message, session: str) -> str:
    reply = call(service, body, session)
    assert isinstance(reply, ErrorReply), reply
    return reply.code


def test_open_requests_and_not_configured(service: ArenaService) -> None:
    assert value(service, Ping(), "anyone")["server"] == service.server_id  # type: ignore[index]
    assert value(service, Contexts(), "anyone") == context_table()
    assert code(service, Reset(), "stranger") == NOT_CONFIGURED
    assert code(service, Step(actions=[0, 0]), "stranger") == NOT_CONFIGURED


def test_ownership_busy_close_and_lease(service: ArenaService, clock: Clock) -> None:
    assert value(service, Configure(seed=5), "a")["rebuilt"] is False  # type: ignore[index]
    assert code(service, Configure(seed=5), "b") == "busy"
    assert code(service, Get(what="obs"), "b") == "busy"
    assert value(service, Close(), "b") is None  # not the owner: nothing happens
    assert code(service, Get(what="state"), "b") == "busy"
    value(service, Close(), "a")
    assert value(service, Configure(seed=5), "b")["rebuilt"] is False  # type: ignore[index]
    clock.now += 11.0  # b falls silent past the lease: a may take over
    value(service, Configure(seed=5), "a")
    assert code(service, Reset(), "b") == "busy"
    value(service, Close(), "a")


def test_configure_rebuilds_exactly_when_needed(service: ArenaService) -> None:
    assert value(service, Configure(seed=5), "c")["rebuilt"] is False  # type: ignore[index]
    value(service, Reset(), "c")
    assert value(service, Configure(seed=5), "c")["rebuilt"] is False  # type: ignore[index]
    value(service, Close(), "c")
    # Another session after episodes were run gets a fresh arena: same seed, same episode.
    assert value(service, Configure(seed=5), "d")["rebuilt"] is True  # type: ignore[index]
    first = value(service, Reset(), "d")
    expected = Arena(seed=5).reset()
    assert all(np.array_equal(a, b) for a, b in zip(first, expected, strict=True))  # type: ignore[call-overload]
    defaults = {"action_space": "abstract", "n_blue": 2}  # stating a default changes nothing
    assert value(service, Configure(seed=5, options=defaults), "d")["rebuilt"] is False  # type: ignore[index]
    opts = {"action_space": "discrete"}
    assert value(service, Configure(seed=5, options=opts), "d")["rebuilt"] is True  # type: ignore[index]
    assert value(service, Get(what="env_info"), "d")["action_space"] == "discrete"  # type: ignore[index]
    value(service, Close(), "d")


def test_refusals_leave_the_episode_untouched(service: ArenaService) -> None:
    value(service, Configure(seed=9), "e")
    local = Arena(seed=9)
    assert code(service, Step(actions=[0, 0]), "e") == "reset_needed"
    value(service, Reset(seed=3), "e")
    local.reset(seed=3)
    bad = [
        b"\xc1",
        msgpack.packb({"v": 1, "type": "step", "session": "e", "actions": "x"}),
        msgpack.packb({"v": 7, "type": "step", "session": "e", "actions": [0, 0]}),
        encode_request(Step(actions=[0, 99]), "e"),
        encode_request(Step(actions=[0]), "e"),
        encode_request(Step(actions=[[1, 2], {}]), "e"),
        encode_request(Reset(contexts={"gravity": 1.0}), "e"),
        encode_request(Configure(options={"warp": 9}), "e"),
        encode_request(Step(actions=[1, 1]), "intruder"),
    ]
    for rep in range(3):
        for payload in bad:
            reply = decode_reply(service.handle(payload))
            assert isinstance(reply, ErrorReply) and reply.code in ERRORS, reply
        actions = [rep % 8, (rep * 3) % 8]
        remote = value(service, Step(actions=actions), "e")
        obs, rewards, done, info = local.step(actions)
        assert all(np.array_equal(a, b) for a, b in zip(remote[0], obs, strict=True))  # type: ignore[index]
        assert remote[1:] == [rewards, done, info]  # type: ignore[index]
    value(service, Close(), "e")


def test_pacer_holds_the_rate() -> None:
    clock = Clock()
    slept: list[float] = []
    pacer = Pacer(0.5, clock=clock, sleep=slept.append)
    pacer.wait()  # the first call never waits
    clock.now += 0.2
    pacer.wait()  # 0.3 s of the period left
    clock.now += 0.5 + 0.3 + 1.0  # a long pause: no burst to catch up afterwards
    pacer.wait()
    pacer.wait()
    assert slept == pytest.approx([0.3, 0.5])
    Pacer(0.0, sleep=slept.append).wait()  # unlimited: returns at once
    assert len(slept) == 2


class LoggedArena(Arena):
    """An ``Arena`` that logs its construction and close; seed 666 fails to build."""

    events: ClassVar[list[tuple[str, int]]] = []

    def __init__(self, seed: int = 1234, **options: object) -> None:
        if seed == 666:
            raise RuntimeError("this arena cannot be built")
        super().__init__(seed, **options)
        LoggedArena.events.append(("built", seed))

    def close(self) -> None:
        LoggedArena.events.append(("closed", self.seed))
        super().close()


def test_a_rebuild_frees_the_old_arenas_before_building_and_survives_a_failed_build() -> None:
    events = LoggedArena.events
    events.clear()
    with ArenaService(LoggedArena, seed=5, arenas=2, clock=Clock()) as svc:  # type: ignore[arg-type]
        events.clear()  # the warm-up's and the first build's
        value(svc, Configure(seed=10, arenas=2), "f")
        # Both old arenas closed before the first new one exists: one set in memory at a time.
        assert events == [("closed", 5), ("closed", 6), ("built", 10), ("built", 11)]
        value(svc, VReset(), "f")
        events.clear()
        assert code(svc, Configure(seed=7, arenas=2, options={"warp": 9}), "f") == "invalid_option"
        assert events == []  # a refused option frees nothing: the episode goes on
        assert code(svc, Configure(seed=2**63 - 1, arenas=2), "f") == "invalid_option"
        assert events == []  # nor does a seed whose last arena would pass 2**63 - 1
        events.clear()
        assert code(svc, Configure(seed=666, arenas=2), "f") == "server_error"
        # The failed build left the old seed's arenas, built again, serving.
        assert events == [("closed", 10), ("closed", 11), ("built", 10), ("built", 11)]
        value(svc, Configure(seed=10, arenas=2), "f")
        first = value(svc, VReset(), "f")
    expected = np.stack([Arena(seed=10).reset(), Arena(seed=11).reset()])
    assert np.array_equal(first["obs"], expected)  # type: ignore[index]


def test_refusals_name_what_exists_and_stay_small() -> None:
    """A K > 1 server's refusal of ``render`` named a 'vrender' that does not exist;
    ``vreset`` with 3 ``seeds`` for 4 arenas said "seed"; an error reply echoed every one of
    100,000 unknown option names (~1 MB)."""
    from neuronsmae.protocol.messages import Render

    with ArenaService(Arena, seed=5, arenas=4, clock=Clock()) as svc:
        value(svc, Configure(seed=5, arenas=4), "f")
        reply = call(svc, Render(), "f")
        assert isinstance(reply, ErrorReply) and reply.code == "malformed_message"
        assert "vrender" not in reply.message and "--arenas 1" in reply.message
        reply = call(svc, Get(what="obs"), "f")
        assert isinstance(reply, ErrorReply) and "'vget'" in reply.message
        reply = call(svc, VReset(seeds=[None] * 3), "f")
        assert isinstance(reply, ErrorReply) and reply.code == "invalid_context"
        assert reply.message.startswith("seeds must have 4 entries"), reply.message
        many = {f"opt{i}": 1 for i in range(100_000)}
        data = svc.handle(encode_request(Configure(seed=5, arenas=4, options=many), "f"))
        assert len(data) < 2_000
        reply = decode_reply(data)
        assert isinstance(reply, ErrorReply) and reply.code == "invalid_option"
        assert "'opt0'" in reply.message and "99992 more, 100000 in all" in reply.message
