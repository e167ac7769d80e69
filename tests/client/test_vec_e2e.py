"""VecRM against real vector servers on loopback ports: parity, isolation, failures, refusals."""

from __future__ import annotations

import signal
import time
from collections.abc import Callable
from typing import Any

import msgpack
import numpy as np
import pytest

from neuronsmae.client import RM, VecRM, ping
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    ResetNeededError,
    ServerUnavailableError,
)
from neuronsmae.protocol.interface import VecArenaAPI
from neuronsmae.protocol.messages import PROTOCOL_VERSION, ErrorReply, OkReply
from neuronsmae.server import VecArena

from .conftest import RawClient, Server

CONTEXTS = [{"level": "easy"}, {"level": 1, "VK1": 0.2}, None, {"coef": 1.5}]


def lockstep(remote: VecArenaAPI, local: VecArenaAPI, steps: int, seed: int = 0) -> int:
    """Drive both with the same requests; every result must match bit for bit. Returns how
    many autoresets happened."""
    rng = np.random.default_rng(seed)
    k = local.num_envs
    contexts = (CONTEXTS * k)[:k]
    assert remote.reset(contexts, seed=[None] * k).tobytes() == local.reset(contexts).tobytes()
    resets, done = 0, np.zeros(k, bool)
    for t in range(steps):
        avail = local.get_avail_actions()
        assert remote.get_avail_actions().tobytes() == avail.tobytes()
        actions = (avail * rng.random(avail.shape)).argmax(-1)
        seeds = [t + 10 * i if i % 2 else None for i in range(k)]
        resets += int(done.sum())
        got, want = remote.step(actions, seeds=seeds), local.step(actions, seeds=seeds)
        assert got[0].tobytes() == want[0].tobytes()
        assert got[1].tobytes() == want[1].tobytes() and got[2].tolist() == want[2].tolist()
        assert got[3] == want[3]
        assert remote.get_state().tobytes() == local.get_state().tobytes()
        done = want[2]
    return resets


@pytest.mark.parametrize("k", [1, 4])
def test_served_arenas_equal_plain_arenas_through_autoresets(
    start_server: Callable[..., Server], k: int
) -> None:
    server = start_server("--arenas", str(k), "--seed", "500")
    with VecRM(seed=31, port=server.port, num_envs=k, launch=False) as remote:
        local = VecArena(seed=31, num_envs=k)
        try:
            assert lockstep(remote, local, steps=120) >= k
        finally:
            local.close()
    assert ping(server.port)["arenas"] == k


def test_two_vector_servers_never_cross_talk(start_server: Callable[..., Server]) -> None:
    a, b = start_server("--arenas", "2"), start_server("--arenas", "3")
    with (
        VecRM(seed=1, port=a.port, num_envs=2, launch=False) as ra,
        VecRM(seed=90, port=b.port, num_envs=3, launch=False) as rb,
    ):
        la, lb = VecArena(seed=1, num_envs=2), VecArena(seed=90, num_envs=3)
        try:
            rng = np.random.default_rng(1)
            for remote, local in ((ra, la), (rb, lb)):
                assert remote.reset().tobytes() == local.reset().tobytes()
            for _ in range(30):  # interleaved: each request must only ever reach its server
                for remote, local in ((ra, la), (rb, lb)):
                    avail = local.get_avail_actions()
                    actions = (avail * rng.random(avail.shape)).argmax(-1)
                    assert remote.step(actions)[0].tobytes() == local.step(actions)[0].tobytes()
        finally:
            la.close()
            lb.close()


def test_several_servers_play_as_one_vector_and_refuse_atomically(
    start_server: Callable[..., Server],
) -> None:
    a, b = start_server("--arenas", "2"), start_server("--arenas", "1")
    with VecRM(seed=7, port=[a.port, b.port], num_envs=3, launch=False) as remote:
        assert remote.shares == [2, 1]
        local = VecArena(seed=7, num_envs=3)
        try:
            lockstep(remote, local, steps=60, seed=3)
            t_before = remote.get_state()[:, -1].copy()
            bad = np.zeros((3, 2), np.int64)
            bad[2, 0] = 9  # only the second server's arena is wrong: nothing may move
            with pytest.raises(InvalidActionError, match="arena 2: agent 0"):
                remote.step(bad)
            with pytest.raises(InvalidContextError, match="arena 1: unknown context key"):
                remote.reset([None, {"speed": 1.0}, None])
            assert remote.get_state()[:, -1].tobytes() == t_before.tobytes()
        finally:
            local.close()


def test_a_server_with_no_active_arena_is_not_asked(
    start_server: Callable[..., Server], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A step whose ``active`` arenas all live on one server goes to that server only, and
    the vector still plays exactly like the in-process one (the other server's arenas stay
    as they were: no reward, not done, empty infos)."""
    a, b = start_server("--arenas", "2"), start_server("--arenas", "2")
    with VecRM(seed=5, port=[a.port, b.port], num_envs=4, launch=False) as remote:
        local = VecArena(seed=5, num_envs=4)
        sent: list[int] = []

        def counting(conn: Any) -> Callable[..., Any]:
            original = conn.send

            def send(body: Any, *args: Any) -> Any:
                sent.append(conn.port)
                return original(body, *args)

            return send

        for conn in remote._conns:
            monkeypatch.setattr(conn, "send", counting(conn))
        try:
            remote.reset(seed=[1, 2, 3, 4])
            local.reset(seed=[1, 2, 3, 4])
            rng = np.random.default_rng(0)
            for t in range(40):
                first = t % 2 == 0  # the first server's arenas, then the second's
                active = np.array([first, first, not first, not first])
                avail = local.get_avail_actions()
                actions = (avail * rng.random(avail.shape)).argmax(-1)
                sent.clear()
                got = remote.step(actions, active=active)
                want = local.step(actions, active=active)
                assert sent == [a.port if first else b.port]
                assert got[0].tobytes() == want[0].tobytes()
                assert got[1].tobytes() == want[1].tobytes()
                assert got[2].tolist() == want[2].tolist() and got[3] == want[3]
                assert remote.get_state().tobytes() == local.get_state().tobytes()
                assert remote.get_avail_actions().tobytes() == local.get_avail_actions().tobytes()
        finally:
            local.close()


def test_counts_must_match_the_server(start_server: Callable[..., Server]) -> None:
    server = start_server("--arenas", "4")
    with pytest.raises(InvalidOptionError, match=r"holds 4 arena\(s\).*asked for 2"):
        VecRM(port=server.port, num_envs=2, launch=False)
    with pytest.raises(InvalidOptionError, match="VecRM"):
        RM(port=server.port, launch=False)
    raw = RawClient(server.port)
    try:
        wire = {"v": PROTOCOL_VERSION, "session": "raw"}
        reply = raw.send(msgpack.packb({**wire, "type": "configure", "arenas": 4}))
        assert isinstance(reply, OkReply) and reply.value["arenas"] == 4
        reply = raw.send(msgpack.packb({**wire, "type": "step", "actions": [0, 0]}))
        assert isinstance(reply, ErrorReply) and reply.code == "malformed_message"
        assert "vstep" in reply.message
        reply = raw.send(msgpack.packb({**wire, "type": "vstep", "actions": [[0, 0]] * 4}))
        assert isinstance(reply, ErrorReply) and reply.code == "reset_needed"
        reply = raw.send(msgpack.packb({**wire, "type": "vreset", "seeds": [1, 2]}))
        assert isinstance(reply, ErrorReply) and reply.code == "invalid_context"
        assert "4 entries" in reply.message
        raw.send(msgpack.packb({**wire, "type": "close"}))
    finally:
        raw.close()


@pytest.mark.slow
def test_private_servers_run_side_by_side_and_stop_on_close() -> None:
    first, second = VecRM(seed=1, num_envs=2), VecRM(seed=1, num_envs=2, servers=2)
    procs = [c.server.proc for v in (first, second) for c in v._conns if c.server is not None]
    try:
        assert len(set(first.ports + second.ports)) == 3 and len(procs) == 3
        assert first.reset().tobytes() == second.reset().tobytes()
        with pytest.raises(ResetNeededError):
            VecRM(num_envs=1).step(np.zeros((1, 2), np.int64))
    finally:
        first.close()
        second.close()
    assert [p.wait(5) for p in procs] == [0, 0, 0]  # each stopped cleanly on close
    for read in (first.get_obs, first.get_state, first.reset):  # not the last reply's arrays
        with pytest.raises(ServerUnavailableError, match="is closed"):
            read()


def test_a_killed_vector_server_gives_a_typed_error_within_the_timeout(
    start_server: Callable[..., Server],
) -> None:
    server = start_server("--arenas", "2")
    remote = VecRM(port=server.port, num_envs=2, launch=False, timeout=2.0)
    try:
        remote.reset()
        server.proc.send_signal(signal.SIGKILL)
        server.proc.wait()
        start = time.monotonic()
        with pytest.raises(ServerUnavailableError):
            remote.step(np.zeros((2, 2), np.int64))
        assert time.monotonic() - start < 1.5  # before the 2 s timeout: noticed, not waited out
    finally:
        remote.close()


def test_a_stopped_vector_server_times_out_as_a_typed_error(
    start_server: Callable[..., Server],
) -> None:
    server = start_server("--arenas", "2")
    remote = VecRM(port=server.port, num_envs=2, launch=False, timeout=1.0)
    try:
        remote.reset()
        server.proc.send_signal(signal.SIGSTOP)  # alive but silent: only the timeout tells
        start = time.monotonic()
        with pytest.raises(ServerUnavailableError, match="within 1 s"):
            remote.step(np.zeros((2, 2), np.int64))
        assert time.monotonic() - start < 5.0  # a guard: the message shows the timeout fired
    finally:
        server.proc.send_signal(signal.SIGCONT)
        remote.close()


@pytest.mark.parametrize("servers", [1, 2])
def test_one_input_rule_whatever_the_server_count(
    start_server: Callable[..., Server], servers: int
) -> None:
    """Rows of arenas that do not step are ignored, every seed and context entry is checked,
    a bot-driven team's actions are ignored: as VecArena does (``tests/server``), on one
    server or several. Two servers refused an inactive arena's bad row; one accepted it."""
    from tests.server import test_vec_inputs as rules

    share = str(4 // servers)
    ports = [start_server("--arenas", share).port for _ in range(servers)]
    with VecRM(seed=0, port=ports, num_envs=4, launch=False, timeout=60, **rules.SHORT) as vec:
        rules.ignored_rows_are_not_checked(vec)
        rules.given_entries_are_checked(vec)
        rules.reset_arguments_are_typed(vec)
    ports = [start_server("--arenas", "1").port for _ in range(2)]
    with VecRM(seed=0, port=ports, num_envs=2, launch=False, mode="competitive") as vec:
        rules.bot_team_rows_are_not_checked(vec)


def test_steps_in_flight_are_settled_before_rows_are_checked(
    start_server: Callable[..., Server],
) -> None:
    """Over several servers the client must know who autoresets: a step still in flight
    that touches an arena of the next step is gathered first."""
    from tests.server.test_vec_inputs import SHORT

    ports = [start_server("--arenas", "1").port for _ in range(2)]
    with VecRM(seed=0, port=ports, num_envs=2, launch=False, **SHORT) as vec:
        vec.reset(seed=0)
        zeros = np.zeros((2, 2), np.int64)
        first = vec.step_async(zeros)
        second = vec.step_async(zeros)  # ends both episodes
        third = vec.step_async(np.full((2, 2), 9))  # both autoreset: rows ignored
        assert not first.result()[2].any() and second.result()[2].all()
        assert not third.result()[2].any()


def test_bad_reset_and_step_seeds_are_refused_as_vecarena_refuses_them(
    start_server: Callable[..., Server],
) -> None:
    """Seeds are per-episode inputs, so a bad one is InvalidContextError, as Arena.reset's
    (a wrong count too: it stays so). Served and in process say the same, before anything
    is sent: 2**64 + 5 does not fit the wire's integers; the vector face follows VecRM."""
    from neuronsmae.client import CoopVectorEnv

    port = start_server("--arenas", "3").port
    zeros = np.zeros((3, 2), np.int64)
    calls: list[tuple[str, Callable[[Any], Any]]] = [
        ("reset 2**64 + 5", lambda v: v.reset(seed=2**64 + 5)),
        ("reset 2**63", lambda v: v.reset(seed=2**63)),
        ("reset last + 2 > max", lambda v: v.reset(seed=2**63 - 2)),
        ("reset [1, 2]", lambda v: v.reset(seed=[1, 2])),
        ("reset entry", lambda v: v.reset(seed=[None, 2**64 + 5, None])),
        ("step entry", lambda v: v.step(zeros, seeds=[None, None, -1])),
        ("step huge", lambda v: v.step(zeros, seeds=[2**70, None, None])),
    ]
    served = VecRM(seed=0, port=port, num_envs=3, launch=False, timeout=60)
    local = VecArena(seed=0, num_envs=3)
    try:
        for vec in (served, local):
            vec.reset(seed=0)
        for name, call in calls:
            said = []
            for vec in (served, local):
                with pytest.raises(InvalidContextError) as caught:
                    call(vec)
                said.append(str(caught.value))
            assert said[0] == said[1] and "seed" in said[0], name
        assert served.step(zeros)[0].tobytes() == local.step(zeros)[0].tobytes()  # intact
    finally:
        served.close()
        local.close()
    faces = [CoopVectorEnv(3, seed=0, port=port, launch=False, timeout=60),
             CoopVectorEnv(3, env="neuronsmae.server:VecArena", seed=0)]  # fmt: skip
    try:
        said = []
        for face in faces:
            with pytest.raises(InvalidContextError) as caught:
                face.reset(seed=2**64 + 5)
            said.append(str(caught.value))
        assert said[0] == said[1] and "seed 18446744073709551621 is out of range" in said[0]
    finally:
        for face in faces:
            face.close()


def test_vector_seeds_and_counts_are_checked_like_vecarena() -> None:
    """``VecRM(seed=None)`` was a builtin TypeError and ``num_envs=np.int64(2)`` refused;
    both are checked before anything is launched."""
    from .conftest import free_port

    port = free_port()
    for seed in (None, 1.5, "3", True):  # num_envs passes (a NumPy integer), the seed not
        with pytest.raises(InvalidOptionError, match=r"seed must be an integer in \[0, "):
            VecRM(seed=seed, port=port, num_envs=np.int64(2))  # type: ignore[arg-type]
    with pytest.raises(InvalidOptionError, match="num_envs must be an integer"):
        VecRM(port=port, num_envs=np.bool_(True))  # type: ignore[arg-type]
    with pytest.raises(ServerUnavailableError):  # nothing was launched
        ping(port, timeout=0.5)
