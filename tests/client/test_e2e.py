"""RM against real servers on loopback ports: parity, isolation, hostile input, failures."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from typing import Any

import msgpack
import numpy as np
import psutil
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from neuronsmae.client import RM, VecRM, context_table, ping
from neuronsmae.protocol import launch
from neuronsmae.protocol.errors import (
    ERRORS,
    BusyError,
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    NeuronsMAEError,
    ResetNeededError,
    ServerUnavailableError,
)
from neuronsmae.protocol.interface import ArenaAPI
from neuronsmae.protocol.link import Link
from neuronsmae.protocol.messages import (
    MESSAGES,
    NOT_CONFIGURED,
    PROTOCOL_VERSION,
    Close,
    Configure,
    ErrorReply,
    OkReply,
    Ping,
    Step,
    encode_request,
    rpc_key,
)
from neuronsmae.server.arena import Arena
from neuronsmae.server.contexts import context_table as local_context_table

from .conftest import RawClient, Server, free_port, same

CONTINUOUS = {"action_space": "continuous", "mode": "competitive"}


@pytest.fixture(scope="module")
def server_a(start_server: Callable[..., Server]) -> Server:
    return start_server()


@pytest.fixture(scope="module")
def server_b(start_server: Callable[..., Server]) -> Server:
    return start_server("--seed", "99")


@pytest.fixture(scope="module")
def raw_b(server_b: Server) -> Iterator[RawClient]:
    raw = RawClient(server_b.port)
    yield raw
    raw.close()


def policy(env: ArenaAPI, rng: np.random.Generator) -> list[Any]:
    """Random valid actions from the availability masks (continuous: random velocities)."""
    continuous = env.get_env_info()["action_space"] == "continuous"
    actions: list[Any] = []
    for mask in env.get_avail_actions():
        choice = int(rng.choice(np.flatnonzero(mask)))
        if continuous:
            actions.append([*rng.uniform(-1.5, 1.5, size=3).tolist(), choice])
        else:
            actions.append(choice)
    return actions


def play_in_lockstep(remote: ArenaAPI, local: ArenaAPI, decisions: int, seed: int = 0) -> None:
    """Drive both arenas with the same actions; every result must match bit for bit."""
    rng = np.random.default_rng(seed)
    assert same(remote.get_env_info(), local.get_env_info())
    contexts = {"Friction_coeff": 0.3, "VK1": 0.5, "coef": 0.8, "level": 1}
    assert same(remote.reset(contexts), local.reset(contexts))
    resets = iter([{"seed": 5}, {"contexts": {"level": "hard"}}, {}])
    for k in range(decisions):
        actions = policy(local, rng)
        result = remote.step(actions)
        assert same(result, local.step(actions))
        if k % 7 == 3 and isinstance(remote, RM):
            remote._cache.clear()  # ask the server instead of reading the step's snapshot
        assert same(remote.get_state(), local.get_state())
        assert same(remote.get_avail_actions(), local.get_avail_actions())
        assert same(remote.get_obs(), local.get_obs())
        if result[2]:
            kwargs = next(resets)
            assert same(remote.reset(**kwargs), local.reset(**kwargs))
    assert same(remote.get_obs(), local.get_obs())


@pytest.mark.parametrize("options", [{}, CONTINUOUS], ids=["abstract-2v2", "continuous-2v2"])
def test_remote_trajectory_equals_in_process(server_a: Server, options: dict[str, Any]) -> None:
    with RM(seed=21, port=server_a.port, launch=False, timeout=10, **options) as remote:
        local = Arena(seed=21, **options)
        try:
            play_in_lockstep(remote, local, decisions=60)
            assert same(remote.render(), local.render())
        finally:
            local.close()


def test_a_busy_polling_server_plays_the_same_and_stops_promptly(
    start_server: Callable[..., Server],
) -> None:
    server = start_server("--busy-poll", "100000")  # polls 0.1 s after every reply
    with RM(seed=22, port=server.port, launch=False, timeout=10) as remote:
        local = Arena(seed=22)
        try:
            play_in_lockstep(remote, local, decisions=40)
        finally:
            local.close()
        remote.step([0, 0])
        t0 = time.monotonic()  # the server is polling for the next request now
        assert server.stop(signal.SIGTERM) == 0  # exited by itself (stop() kills after 10 s)
    assert time.monotonic() - t0 < 5.0  # a guard; the exit status above is the check


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"busy_poll_us": -1.0}, "busy_poll_us must be in [0, 100000] microseconds, got -1.0"),
        (
            {"busy_poll_us": 1e9},
            "busy_poll_us must be in [0, 100000] microseconds, got 1000000000.0",
        ),
        ({"busy_poll_us": float("nan")}, "busy_poll_us must be in [0, 100000] microseconds"),
        ({"time_scale": -1.0}, "time_scale must be a finite number >= 0 (0 = unlimited)"),
        ({"time_scale": float("inf")}, "time_scale must be a finite number >= 0"),
        # a vector's last arena is seeded seed + num_envs - 1: its bound is 2⁶³ − num_envs
        ({"seed": -1}, "seed must be an integer in [0, 922337203685477580"),
        ({"seed": 1.5}, "seed must be an integer in [0, 922337203685477580"),
        ({"timeout": 0}, "timeout must be a finite number of seconds > 0, got 0"),
        ({"timeout": float("nan")}, "timeout must be a finite number of seconds > 0, got nan"),
    ],
)
def test_bad_launch_settings_are_refused_before_anything_starts(
    kwargs: dict[str, float], message: str
) -> None:
    port = free_port()
    with pytest.raises(InvalidOptionError) as caught:
        VecRM(port=port, num_envs=2, **kwargs)
    assert message in str(caught.value)
    with pytest.raises(InvalidOptionError) as caught:
        RM(port=port, **kwargs)
    assert message in str(caught.value)
    with pytest.raises(ServerUnavailableError):  # nothing was launched
        ping(port, timeout=0.5)


@pytest.mark.parametrize("port", [0, 65536, True, "10000"])
def test_a_bad_port_is_refused_before_anything_starts(port: object) -> None:
    with pytest.raises(InvalidOptionError, match=r"port must be an integer in 1\.\.65535"):
        RM(port=port)  # type: ignore[arg-type]
    with pytest.raises(InvalidOptionError, match=r"port must be an integer in 1\.\.65535"):
        VecRM(port=port, num_envs=2)  # type: ignore[arg-type]
    with pytest.raises(InvalidOptionError, match=r"port must be an integer in 1\.\.65535"):
        ping(port)  # type: ignore[arg-type]
    with pytest.raises(InvalidOptionError, match=r"port must be an integer in 1\.\.65535"):
        context_table(port)  # type: ignore[arg-type]


@pytest.mark.parametrize("router", ["10.0.0.1:7447", "", "tcp/", 7447])
def test_a_router_that_is_no_locator_is_refused_before_any_session(router: object) -> None:
    """Zenoh's own refusal was a configuration parse error out of its Rust sources."""
    for make in (lambda: RM(port=10000, router=router), lambda: VecRM(port=10000, router=router)):
        with pytest.raises(InvalidOptionError, match="router must be a Zenoh locator"):
            make()  # type: ignore[arg-type]


def test_a_port_listed_twice_is_refused_before_anything_starts() -> None:
    """``VecRM(port=[P, P])`` used to connect twice and be refused by its own server as
    busy."""
    with pytest.raises(InvalidOptionError, match=r"listed twice: \[10000\]"):
        VecRM(port=[10000, 10001, 10000], num_envs=3)


@pytest.mark.parametrize("timeout", [0, -1.0, float("inf"), "2"])
def test_a_query_without_a_finite_positive_timeout_is_refused(timeout: object) -> None:
    with pytest.raises(InvalidOptionError, match="timeout must be a finite number of seconds"):
        ping(free_port(), timeout=timeout)  # type: ignore[arg-type]


@pytest.mark.slow
def test_the_server_refuses_a_bad_busy_poll() -> None:
    cmd = [sys.executable, "-m", "neuronsmae.server", "--port", str(free_port())]
    done = subprocess.run([*cmd, "--busy-poll", "-5"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert "--busy-poll must be in 0..100000 microseconds" in done.stderr


def test_rm_keeps_the_interface_and_its_docstrings() -> None:
    for name in ArenaAPI.__abstractmethods__:
        assert getattr(RM, name).__doc__ == getattr(ArenaAPI, name).__doc__


def test_two_servers_never_cross_talk(server_a: Server, server_b: Server) -> None:
    assert ping(server_a.port)["server"] != ping(server_b.port)["server"]
    with (
        RM(seed=1, port=server_a.port, launch=False) as ra,
        RM(seed=2, port=server_b.port, launch=False) as rb,
    ):
        la, lb = Arena(seed=1), Arena(seed=2)
        rng = np.random.default_rng(3)
        assert same(ra.reset(), la.reset()) and same(rb.reset(), lb.reset())
        assert not same(ra.get_state(), rb.get_state())
        for _ in range(5):
            acts = policy(la, rng)
            assert same(rb.step(acts), lb.step(acts))
            assert same(ra.get_obs(), la.get_obs())  # b's steps never reach a
            assert same(ra.step(acts), la.step(acts))
    raw = RawClient(server_a.port)
    try:  # a session connected to a cannot reach b's key
        assert raw.send(encode_request(Ping()), key=rpc_key(server_b.port), timeout=1.0) is None
    finally:
        raw.close()


def test_second_client_is_refused_until_the_owner_closes(server_a: Server) -> None:
    with RM(seed=3, port=server_a.port, launch=False) as first:
        with pytest.raises(BusyError, match="owned by another client"):
            RM(seed=3, port=server_a.port, launch=False)
        first.reset()
    with pytest.raises(ServerUnavailableError, match="is closed"):
        first.get_obs()  # not the last reply's observations
    with RM(seed=3, port=server_a.port, launch=False) as second:
        assert same(second.reset(), Arena(seed=3).reset())


def test_typed_errors_reach_the_caller(server_a: Server) -> None:
    with pytest.raises(InvalidOptionError, match="warp"):
        RM(port=server_a.port, launch=False, warp=9)
    with RM(seed=4, port=server_a.port, launch=False, timeout=5) as env:
        with pytest.raises(ResetNeededError):
            env.step([0, 0])
        env.reset()
        with pytest.raises(InvalidActionError):
            env.step([99, 0])
        with pytest.raises(InvalidActionError):
            env.step([object(), 0])
        with pytest.raises(InvalidContextError, match="gravity"):
            env.reset({"gravity": 1.0})
    assert context_table(server_a.port) == local_context_table()


def test_rm_refuses_and_accepts_what_arena_does(server_a: Server) -> None:
    """RM played a dict's keys, took a set in arbitrary order, raised builtin errors for
    ``step(None)``, ``step(3)`` and ``reset("VK1")``, and refused NumPy context values."""
    import numpy as np

    from neuronsmae.server import Arena

    local = Arena(seed=4)
    with RM(seed=4, port=server_a.port, launch=False, timeout=30) as env:
        for arena in (env, local):
            arena.reset()
            for bad in ({0: 3, 1: 5}, {3, 5}, "35", b"35", None, 3, np.array(3)):
                with pytest.raises(InvalidActionError, match="a sequence of 2 per-agent"):
                    arena.step(bad)  # type: ignore[arg-type]
            with pytest.raises(InvalidContextError, match="contexts must be a mapping"):
                arena.reset("VK1")  # type: ignore[arg-type]
        contexts = {"VK1": np.float32(0.25), "coef": np.int64(2), "level": np.int32(1)}
        got, want = env.reset(contexts, seed=3), local.reset(contexts, seed=3)
        assert np.stack(got).tobytes() == np.stack(want).tobytes()
        with pytest.raises(InvalidContextError, match="'coef' must be a number"):
            env.reset({"coef": np.bool_(True)})
    local.close()


BAD_SEEDS = [2**63, 2**64 + 5, -1, True, 1.5, "3", np.uint64(2**64 - 1)]
"""Reset seeds an arena refuses: out of [0, 2**63 - 1] (2**64 + 5 does not even fit the
wire's integers), or not an integer."""


def test_a_bad_reset_seed_is_refused_as_the_arena_refuses_it(server_a: Server) -> None:
    """Served, 2**63 came back as the server's MalformedMessageError and 2**64 + 5 as
    "cannot encode message: Integer value out of range", naming no seed. Now RM checks the
    seed before sending, with the arena's own check: same type, same message."""
    local = Arena(seed=4)
    with RM(seed=4, port=server_a.port, launch=False, timeout=30) as env:
        env.reset(seed=1)
        for seed in BAD_SEEDS:
            said = []
            for arena in (env, local):
                with pytest.raises(NeuronsMAEError) as caught:
                    arena.reset(seed=seed)  # type: ignore[arg-type]
                said.append((type(caught.value), str(caught.value)))
            assert said[0] == said[1], seed
            assert said[0][0] is InvalidContextError
            assert "seed" in said[0][1] and "[0, 9223372036854775807]" in said[0][1]
        top = np.uint64(2**63 - 1)  # the largest seed, as a NumPy integer: accepted by both
        assert same(env.reset(seed=top), local.reset(seed=top))  # type: ignore[arg-type]
    local.close()


def _raw(**fields: Any) -> bytes:
    wire = {"v": PROTOCOL_VERSION, "session": "hostile", **fields}
    return msgpack.packb(wire, use_bin_type=True)


MALFORMED = {
    "random-bytes": (b"\x00\xff\xc1garbage", "malformed_message"),
    "empty": (b"", "malformed_message"),
    "not-a-map": (msgpack.packb([1, "step"]), "malformed_message"),
    "unknown-type": (_raw(type="teleport"), "malformed_message"),
    "wrong-type-actions": (_raw(type="step", actions="left"), "malformed_message"),
    "wrong-type-seed": (_raw(type="reset", seed="7"), "malformed_message"),
    "missing-field": (_raw(type="get"), "malformed_message"),
    "extra-field": (_raw(type="ping", sudo=True), "malformed_message"),
    "huge": (b"\x00" * (2 << 20), "message_too_large"),
    "huge-but-valid": (_raw(type="step", actions=[0] * 1_200_000), "message_too_large"),
    "wrong-version": (msgpack.packb({"v": 3, "type": "ping", "session": "s"}), "version_mismatch"),
    "no-version": (msgpack.packb({"type": "ping", "session": "s"}), "malformed_message"),
    "not-configured": (encode_request(Step(actions=[0, 0]), "stranger"), NOT_CONFIGURED),
    "bad-option": (encode_request(Configure(options={"warp": 9}), "x"), "invalid_option"),
}


@pytest.mark.parametrize("case", MALFORMED, ids=list(MALFORMED))
def test_malformed_input_gets_a_typed_error(raw_b: RawClient, case: str) -> None:
    payload, code = MALFORMED[case]
    reply = raw_b.send(payload)
    assert isinstance(reply, ErrorReply) and reply.code == code, reply
    assert isinstance(raw_b.send(encode_request(Ping())), OkReply)


def test_refused_requests_leave_the_episode_intact(server_b: Server, raw_b: RawClient) -> None:
    with RM(seed=8, port=server_b.port, launch=False) as remote:
        local = Arena(seed=8)
        rng = np.random.default_rng(8)
        assert same(remote.reset(), local.reset())
        owner = remote.session_id
        hostile = [
            *(payload for payload, _ in MALFORMED.values()),
            encode_request(Step(actions=[0, 99]), owner),
            encode_request(Step(actions=[0]), owner),
            _raw(type="step", session=owner, actions=[[1, 2], {"x": 1}]),
            _raw(type="reset", session=owner, contexts={"gravity": 1}),
            encode_request(Configure(seed=1), "usurper"),
            encode_request(Step(actions=[1, 1]), "usurper"),
        ]
        for _ in range(4):
            for payload in hostile:
                assert isinstance(raw_b.send(payload), ErrorReply)
            actions = policy(local, rng)
            assert same(remote.step(actions), local.step(actions))


scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(), st.text(max_size=8)
)
wire_values = st.recursive(
    scalars,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=3)
    ),
    max_leaves=10,
)
request_maps = st.fixed_dictionaries(
    {"session": st.just("fuzz")},
    optional={
        "v": st.one_of(st.just(PROTOCOL_VERSION), wire_values),
        "type": st.one_of(st.sampled_from(sorted(MESSAGES)), st.text(max_size=10)),
        "seed": wire_values,
        "options": wire_values,
        "contexts": wire_values,
        "actions": wire_values,
        "what": st.one_of(st.sampled_from(["obs", "state", "env_info"]), wire_values),
        "junk": wire_values,
    },
).map(lambda wire: msgpack.packb(wire, use_bin_type=True))


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(st.one_of(st.binary(max_size=256), request_maps))
def test_fuzzed_payloads_leave_the_server_answering(raw_b: RawClient, payload: bytes) -> None:
    reply = raw_b.send(payload)
    assert isinstance(reply, OkReply) or (
        isinstance(reply, ErrorReply) and reply.code in {*ERRORS, NOT_CONFIGURED}
    ), reply


def test_server_still_correct_after_fuzzing(server_b: Server, raw_b: RawClient) -> None:
    raw_b.send(encode_request(Close(), "fuzz"))  # in case the fuzz configured the server
    with RM(seed=12, port=server_b.port, launch=False) as remote:
        local = Arena(seed=12)
        play_in_lockstep(remote, local, decisions=5, seed=12)


def test_dead_hung_and_restarted_server(start_server: Callable[..., Server]) -> None:
    port = free_port()
    server = start_server(port=port)
    env = RM(seed=3, port=port, launch=False, timeout=2.0)
    try:
        env.reset()
        server.proc.send_signal(signal.SIGSTOP)  # hung: the query times out
        t0 = time.monotonic()
        with pytest.raises(ServerUnavailableError, match="within 2 s"):
            env.get_env_info()
        assert 1.5 < time.monotonic() - t0 < 6.0  # waited for the timeout, and not for good
        server.proc.send_signal(signal.SIGCONT)
        server.proc.kill()  # dead: Zenoh ends the query at once
        server.proc.wait()
        t0 = time.monotonic()
        with pytest.raises(ServerUnavailableError):
            env.step([0, 0])
        assert time.monotonic() - t0 < 1.5  # before the 2 s timeout: noticed, not waited out
        restarted = start_server(port=port)  # back: the client configures it again
        deadline = time.monotonic() + 30
        while True:
            try:
                obs = env.reset()
                break
            except ServerUnavailableError:
                assert time.monotonic() < deadline, "the client never reconnected"
                time.sleep(0.2)
        assert same(obs, Arena(seed=3).reset())
    finally:
        env.close()
    t0 = time.monotonic()
    assert restarted.stop(signal.SIGTERM) == 0  # exited by itself (stop() kills after 10 s)
    assert time.monotonic() - t0 < 5.0


def test_port_in_use_fails_clearly(server_a: Server) -> None:
    cmd = [sys.executable, "-m", "neuronsmae.server", "--port", str(server_a.port)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert f"port {server_a.port} on 127.0.0.1 is already in use" in done.stderr


def test_a_private_launch_on_a_port_taken_meanwhile_moves_on(
    server_a: Server, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Two launchers on one machine can pick the same free port; the one whose server
    lost the bind must not take the winner's answer for its own and claim it."""
    picks = iter([server_a.port])
    real = launch.free_port
    monkeypatch.setattr(launch, "free_port", lambda host: next(picks, None) or real(host))
    env = RM(seed=4)  # its first server exits (port in use), the second gets a fresh port
    try:
        assert env._conn.port != server_a.port
        assert env._conn.server is not None
        assert ping(env._conn.port)["pid"] == env._conn.server.proc.pid
        assert ping(server_a.port)["owned"] is False  # the winner was never claimed
        assert same(env.reset(), Arena(seed=4).reset())
    finally:
        env.close()


def test_an_explicit_port_taken_while_launching_is_joined(
    server_a: Server, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Connect-or-launch on an explicit port: a server that binds the port between the
    look and the launch is the one connected to (the launched one exits, port in use)."""
    real, looks = Link.open, []

    def open_(self: Link) -> bool:
        looks.append(self.port)
        return len(looks) > 1 and real(self)  # the first look finds nothing listening

    monkeypatch.setattr(Link, "open", open_)
    env = RM(seed=4, port=server_a.port)
    try:
        assert env._conn.server is None  # it launched none that lives
        assert ping(server_a.port)["owned"] is True
        assert same(env.reset(), Arena(seed=4).reset())
    finally:
        env.close()
    assert ping(server_a.port)["owned"] is False


@pytest.mark.slow
def test_launch_paces_then_stops_its_server() -> None:
    port = free_port()
    with pytest.raises(ServerUnavailableError, match="launch=False"):
        RM(port=port, launch=False)
    env = RM(seed=4, port=port, time_scale=4)  # 0.4 s decisions at 4x: 0.1 s each
    try:
        assert env._conn.server is not None
        proc = env._conn.server.proc
        assert ping(port)["owned"] is True
        assert same(env.reset(), Arena(seed=4).reset())
        t0 = time.monotonic()
        for _ in range(5):
            env.step([0, 0])
        assert time.monotonic() - t0 >= 0.4
    finally:
        env.close()
    assert proc.poll() == 0
    with pytest.raises(ServerUnavailableError):
        ping(port, timeout=0.5)
    env.close()  # twice is fine


ORPHAN = """
import sys
from neuronsmae.client import RM
env = RM(port=int(sys.argv[1]), time_scale=0)
print(env._conn.server.proc.pid, flush=True)
sys.stdin.read()  # wait to be killed
"""


@pytest.mark.slow
def test_launched_server_exits_when_its_client_is_killed() -> None:
    port = free_port()
    with subprocess.Popen(  # leaving closes the pipes and waits
        [sys.executable, "-c", ORPHAN, str(port)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    ) as client:
        try:
            server_pid = int(client.stdout.readline())  # type: ignore[union-attr]
            assert ping(port)["owned"] is True
        finally:
            client.kill()  # no close(): the server must notice on its own
    deadline = time.monotonic() + 5.0
    while _alive(server_pid):
        assert time.monotonic() < deadline, "the launched server outlived its client"
        time.sleep(0.05)
    with pytest.raises(ServerUnavailableError):
        ping(port, timeout=0.5)


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
