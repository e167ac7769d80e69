"""``RM``: the NeuronsMAE arena served by a ``neuronsmae-server``, used like the local one.

``RM`` implements :class:`~neuronsmae.protocol.interface.ArenaAPI` over Zenoh, so training
code written against ``neuronsmae.server.Arena`` runs unchanged against a server in another
process or on another machine, with the same seed giving the same trajectory bit for bit.
"""

from __future__ import annotations

import uuid
import weakref
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.client.launcher import ServerProcess, check_launch, is_local
from neuronsmae.client.link import Link
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    MalformedMessageError,
    MessageTooLargeError,
    NeuronsMAEError,
    ServerError,
    ServerUnavailableError,
    error_from_code,
)
from neuronsmae.protocol.interface import Action, ArenaAPI, inherit_docstrings
from neuronsmae.protocol.messages import (
    MAX_REQUEST_BYTES,
    NOT_CONFIGURED,
    Close,
    Configure,
    Contexts,
    ErrorReply,
    Get,
    Message,
    OkReply,
    Ping,
    Render,
    Reply,
    Reset,
    Step,
    decode_reply,
    encode_request,
)

CLOSE_TIMEOUT = 1.0
"""Seconds ``close`` waits for the server to acknowledge, so closing never hangs."""


def _shutdown(link: Link, server: ServerProcess | None, farewell: bytes | None) -> None:
    """Release the server and the session (runs once, from close() or garbage collection)."""
    try:
        if farewell is not None and server is None:
            link.call(farewell, CLOSE_TIMEOUT)
    except NeuronsMAEError:
        pass  # the server is gone or busy: nothing left to release
    finally:
        link.close()
        if server is not None:
            server.stop()


@inherit_docstrings
class RM(ArenaAPI):
    """A remote arena on ``tcp/host:port``; started locally if nothing answers there.

    ``seed`` and ``**options`` (the ``Arena`` options: ``action_space``, ``n_blue``, ...)
    configure the server's arena exactly as ``Arena(seed, **options)`` would. With
    ``launch=True`` and nothing listening on a local ``host:port``, a server is started
    there (with ``time_scale``, ``no_graphics`` and ``busy_poll_us``, which only apply to a
    server launched this way) and stopped by :meth:`close`. Every request waits at most
    ``timeout`` seconds, then raises ``ServerUnavailableError``; if the server comes back,
    the next request configures it again and carries on (the episode in progress is lost).

    ``busy_poll_us`` (``neuronsmae-server --busy-poll``) has the launched server poll for
    the next request that many microseconds after each reply instead of sleeping at once.
    With a core to spare it cuts the round trip (``docs/benchmarks.md``); where servers
    share cores it only burns CPU, so it is off by default.

    ``router`` (a Zenoh locator such as ``"tcp/10.0.0.1:7447"``) reaches the server on
    ``port`` through that router instead of at ``host``: for servers started with
    ``--router`` on machines this one cannot connect to directly. Nothing is launched then.
    """

    def __init__(
        self,
        seed: int = 1234,
        port: int = 10000,
        no_graphics: bool = True,
        time_scale: float = 100,
        host: str = "127.0.0.1",
        launch: bool = True,
        timeout: float = 10.0,
        router: str | None = None,
        busy_poll_us: float = 0.0,
        **options: Any,
    ) -> None:
        check_launch(time_scale, busy_poll_us)
        self.seed, self.port, self.host, self.timeout = seed, port, host, float(timeout)
        self.router = router
        self.options = dict(options)
        self.session_id = uuid.uuid4().hex
        self._link = Link(host, port, router)
        self._server: ServerProcess | None = None
        self._closer: weakref.finalize | None = None
        self._cache: dict[str, Any] = {}
        """What the last reset/step left: obs, state, avail_actions (private copies)."""
        try:
            self._connect(launch, no_graphics, time_scale, busy_poll_us)
            farewell = encode_request(Close(), self.session_id)
            self._closer = weakref.finalize(self, _shutdown, self._link, self._server, farewell)
            self._configure()
        except BaseException:
            self.close()
            raise

    # ---- connection --------------------------------------------------------------------

    def _connect(
        self, launch: bool, no_graphics: bool, time_scale: float, busy_poll_us: float
    ) -> None:
        if self._link.open():
            return
        where = self._link.where
        if self.router:
            raise ServerUnavailableError(f"cannot reach the Zenoh router for {where}")
        if not launch:
            raise ServerUnavailableError(f"no server listens on {where} (launch=False)")
        if not is_local(self.host):
            raise ServerUnavailableError(
                f"no server listens on {where}; servers are only launched on this machine"
            )
        self._server = ServerProcess(
            self.port, self.seed, self.host, time_scale, no_graphics, busy_poll_us
        )
        self._server.wait_ready(self._answers)

    def _answers(self) -> bool:
        """Whether a server answers a ping now (used while a launched server starts)."""
        try:
            self._link.call(encode_request(Ping(), self.session_id), min(self.timeout, 1.0))
        except ServerUnavailableError:
            return False
        return True

    def _configure(self) -> None:
        self._cache.clear()
        self._call(Configure(seed=self.seed, options=self.options), InvalidOptionError)

    # ---- one request -------------------------------------------------------------------

    def _call(
        self, body: Message, bad_input: type[NeuronsMAEError] = MalformedMessageError
    ) -> OkReply:
        """Send ``body``, return the reply or raise the server's error as its type.

        ``bad_input`` is the error raised when the arguments cannot even be encoded, the
        same type the in-process arena raises for unusable arguments.
        """
        if self._closer is not None and not self._closer.alive:
            raise ServerUnavailableError("this RM is closed")
        try:
            data = encode_request(body, self.session_id)
        except MalformedMessageError as exc:
            raise bad_input(str(exc)) from exc
        if len(data) > MAX_REQUEST_BYTES:
            raise MessageTooLargeError(
                f"request of {len(data)} bytes exceeds the limit of {MAX_REQUEST_BYTES}"
            )
        reply = self._send(data)
        if isinstance(reply, ErrorReply) and reply.code == NOT_CONFIGURED:
            self._configure()  # the server restarted: claim it again, then retry once
            reply = self._send(data)
        if isinstance(reply, ErrorReply):
            raise error_from_code(reply.code, reply.message)
        return reply

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

    def _send(self, data: bytes) -> Reply:
        raw = self._link.call(data, self.timeout)
        try:
            return decode_reply(raw)
        except MalformedMessageError as exc:
            raise ServerError(f"unreadable reply from {self._link.where}: {exc}") from exc

    # ---- ArenaAPI ----------------------------------------------------------------------

    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        wire = None if contexts is None else dict(contexts)
        self._cache.clear()
        reply = self._call(Reset(contexts=wire, seed=seed), InvalidContextError)
        obs = list(reply.value)
        self._remember(obs, reply)
        return obs

    def step(
        self, actions: Sequence[Action]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        wire = actions if isinstance(actions, np.ndarray) else list(actions)
        self._cache.clear()
        reply = self._call(Step(actions=wire), InvalidActionError)
        if not isinstance(reply.value, list) or len(reply.value) != 4:
            raise ServerError("the server's step reply is not [obs, rewards, done, info]")
        obs, rewards, done, info = reply.value
        self._remember(obs, reply)
        return obs, rewards, done, info

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
        if self._closer is not None:
            self._closer()  # releases the server once; later calls do nothing
        else:  # construction failed before the finalizer existed
            self._link.close()
            if self._server is not None:
                self._server.stop()

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
    link = Link(host, port)
    try:
        reply = decode_reply(link.call(encode_request(body), timeout))
    finally:
        link.close()
    if isinstance(reply, ErrorReply):
        raise error_from_code(reply.code, reply.message)
    return reply.value


def ping(port: int = 10000, host: str = "127.0.0.1", timeout: float = 2.0) -> dict[str, Any]:
    """Ask the server on ``host:port`` who it is: protocol ``version``, ``server`` id,
    whether it is ``owned`` by a client, its ``time_scale``. Raises ServerUnavailableError."""
    return _query(Ping(), port, host, timeout)


def context_table(
    port: int = 10000, host: str = "127.0.0.1", timeout: float = 2.0
) -> list[dict[str, Any]]:
    """The server's reset contexts: one row per key with its default and range or choices."""
    return _query(Contexts(), port, host, timeout)
