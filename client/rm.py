"""``RM``: the NeuronsMAE arena served by a ``neuronsmae-server``, used like the local one.

``RM`` implements :class:`~neuronsmae.protocol.interface.ArenaAPI` over Zenoh, so training
code written against ``neuronsmae.server.Arena`` runs unchanged against a server in another
process or on another machine, with the same seed giving the same trajectory bit for bit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.client.connection import Connection
from neuronsmae.client.connection import answering_pid as pid_on_link
from neuronsmae.protocol.actions import check_sequence, is_sequence
from neuronsmae.protocol.defaults import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    DEFAULT_SEED,
    RELEASED_TIME_SCALE,
)
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    NeuronsMAEError,
    ServerError,
    error_from_code,
)
from neuronsmae.protocol.interface import (
    Action,
    ArenaAPI,
    inherit_docstrings,
    plain_contexts,
    seed_value,
)
from neuronsmae.protocol.launch import ServerCommand, check_launch, check_timeout, ports_of
from neuronsmae.protocol.link import Link
from neuronsmae.protocol.messages import (
    Configure,
    Contexts,
    ErrorReply,
    Get,
    Message,
    OkReply,
    Ping,
    Render,
    Reset,
    Step,
    decode_reply,
    encode_request,
)


@inherit_docstrings
class RM(ArenaAPI):
    """A remote arena on ``tcp/host:port``; started locally if nothing answers there.

    ``seed`` and ``**options`` (the ``Arena`` options: ``action_space``, ``n_blue``, ...)
    configure the server's arena exactly as ``Arena(seed, **options)`` would. ``port=None``
    (the default) launches a private server on a free loopback port, so any number of
    clients run side by side; an explicit port (the released wrapper's call,
    ``RM(seed=1234, port=10000, ...)``) uses the server there, or starts one on it when
    nothing listens on a local ``host`` and ``launch`` is True. ``time_scale`` and
    ``busy_poll_us`` only apply to a server launched this way, which is stopped by
    :meth:`close`. ``no_graphics`` is the released signature's flag and changes nothing: a
    3-D window opens only with the ``gui`` option, and ``render()`` returns frames either
    way. Every request waits at most ``timeout`` seconds, then raises
    ``ServerUnavailableError``; if the server comes back, the next request configures it
    again and carries on (the episode in progress is lost).

    ``time_scale`` caps simulated time at that many times real time (the released build's
    Unity time scale; 100 by default, as released; 0 = unlimited).

    ``busy_poll_us`` (``neuronsmae-server --busy-poll``) has the launched server poll for
    the next request that many microseconds after each reply instead of sleeping at once.
    With a core to spare it cuts the round trip (``docs/benchmarks.md``); where servers
    share cores it only burns CPU, so it is off by default.

    ``router`` (a Zenoh locator such as ``"tcp/10.0.0.1:7447"``) reaches the server on
    ``port`` through that router instead of at ``host``: for servers started with
    ``--router`` on machines this one cannot connect to directly. Nothing is launched then.

    An ``RM`` drives a one-arena server; for servers started with ``--arenas K`` use
    :class:`~neuronsmae.client.vec_rm.VecRM`.
    """

    def __init__(
        self,
        seed: int = DEFAULT_SEED,
        port: int | None = None,
        no_graphics: bool = True,
        time_scale: float = RELEASED_TIME_SCALE,
        host: str = DEFAULT_HOST,
        launch: bool = True,
        timeout: float = 10.0,
        router: str | None = None,
        busy_poll_us: float = 0.0,
        **options: Any,
    ) -> None:
        check_launch(time_scale, busy_poll_us, seed=seed)
        self.seed, self.host, self.timeout = seed, host, float(timeout)
        self.router = router
        self.options = dict(options)
        self._cache: dict[str, Any] = {}
        """What the last reset/step left: obs, state, avail_actions (private copies)."""
        self._agents: int | None = None
        """``n_agents``, asked once (it does not change while this client lives)."""
        self._conn = Connection(
            port=port,
            command=lambda p: ServerCommand(
                p, seed, host, time_scale=time_scale, busy_poll_us=busy_poll_us
            ),
            configure=Configure(seed=seed, options=self.options),
            host=host,
            router=router,
            launch=launch,
            timeout=timeout,
        )
        self.port = self._conn.port
        self.session_id = self._conn.session_id

    # ---- one request -------------------------------------------------------------------

    def _call(
        self, body: Message, bad_input: type[NeuronsMAEError] = InvalidActionError
    ) -> OkReply:
        """Send ``body``; return the reply or raise the server's error as its type."""
        return self._conn.call(body, bad_input)

    def _remember(self, obs: list[np.ndarray], reply: OkReply) -> None:
        """Keep copies of what the arena looks like now, until the next reset or step."""
        snapshot = reply.snapshot or {}
        if {"state", "avail_actions"} <= snapshot.keys():
            self._cache = {"obs": _copy(obs), **snapshot}

    def _read(self, what: str) -> Any:
        """``get_<what>`` from the cache when fresh (as copies, like the arena), else asked."""
        if what in self._cache:
            return _copy(self._cache[what])
        return self._call(Get(what=what)).value

    # ---- ArenaAPI ----------------------------------------------------------------------

    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        wire = plain_contexts(contexts)
        # Checked here as Arena.reset checks it (same error, naming seed and the valid range):
        # the wire would refuse it as a malformed message, or fail to encode it at all.
        checked = None if seed is None else seed_value(seed)
        self._cache.clear()
        reply = self._call(Reset(contexts=wire, seed=checked), InvalidContextError)
        obs = list(reply.value)
        self._remember(obs, reply)
        return obs

    def step(
        self, actions: Sequence[Action]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        if not is_sequence(actions):  # what list() would misread: refused as Arena does
            check_sequence(actions, self._n_agents())
        wire = actions if isinstance(actions, np.ndarray) else list(actions)
        self._cache.clear()
        reply = self._call(Step(actions=wire), InvalidActionError)
        if not isinstance(reply.value, list) or len(reply.value) != 4:
            raise ServerError("the server's step reply is not [obs, rewards, done, info]")
        obs, rewards, done, info = reply.value
        self._remember(obs, reply)
        return obs, rewards, done, info

    def _n_agents(self) -> int:
        """How many agents act (for messages), asked once."""
        if self._agents is None:
            self._agents = int(self.get_env_info()["n_agents"])
        return self._agents

    def get_obs(self) -> list[np.ndarray]:
        return self._read("obs")

    def get_state(self) -> np.ndarray:
        return self._read("state")

    def get_avail_actions(self) -> list[np.ndarray]:
        return self._read("avail_actions")

    def get_env_info(self) -> dict[str, Any]:
        return self._read("env_info")

    def render(self) -> np.ndarray:
        return self._call(Render()).value

    def close(self) -> None:
        self._cache.clear()  # no answers from a closed client: every read says it is closed
        self._conn.close()

    def __enter__(self) -> RM:
        return self


def _copy(value: Any) -> Any:
    """Fresh arrays in fresh lists, so callers may modify what they get."""
    if isinstance(value, np.ndarray):
        return value.copy()
    if isinstance(value, list):
        return [_copy(v) for v in value]
    return value


def _query(body: Message, port: int, host: str, timeout: float) -> Any:
    ports_of(port)
    check_timeout(timeout)
    link = Link(host, port)
    try:
        reply = decode_reply(link.call(encode_request(body), timeout))
    finally:
        link.close()
    if isinstance(reply, ErrorReply):
        raise error_from_code(reply.code, reply.message)
    return reply.value


def ping(
    port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, timeout: float = 2.0
) -> dict[str, Any]:
    """Ask the server on ``host:port`` who it is: protocol ``version``, ``server`` id,
    whether it is ``owned`` by a client, its ``time_scale`` and how many ``arenas`` it
    holds, and its ``pid``. Raises ServerUnavailableError."""
    return _query(Ping(), port, host, timeout)


def answering_pid(port: int, host: str = DEFAULT_HOST, timeout: float = 1.0) -> int | None:
    """The pid of the server answering a ping on ``host:port``, None while none answers:
    a launcher waits for its own server's pid, since another may hold a port it picked."""
    link = Link(host, port)
    try:
        return pid_on_link(link, timeout=timeout)
    finally:
        link.close()


def context_table(
    port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, timeout: float = 2.0
) -> list[dict[str, Any]]:
    """The server's reset contexts: one row per key with its default and range or choices."""
    return _query(Contexts(), port, host, timeout)
