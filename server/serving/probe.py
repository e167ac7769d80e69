"""Ping a server through the protocol's ``ping`` message, from the server package's side.

The server package must not import the client, so this is the few lines of Zenoh the fleet
launcher (:mod:`neuronsmae.server.serving.fleet`) needs to tell whether a server answers: its own
client session per server, a timeout on every query, and a :class:`Health` record instead
of an exception, because for a supervisor "down" is an answer, not an error.
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass

import zenoh

from neuronsmae.protocol.errors import MalformedMessageError
from neuronsmae.protocol.messages import (
    ErrorReply,
    Ping,
    decode_reply,
    encode_request,
    rpc_key,
)
from neuronsmae.protocol.transport import client_config, endpoint

WILDCARDS = {"0.0.0.0": "127.0.0.1", "": "127.0.0.1", "::": "::1", "[::]": "::1"}
"""A server listening on every address is pinged on the loopback of the same family."""


@dataclass(frozen=True)
class Health:
    """What one ping found out about the server on ``port``."""

    port: int
    up: bool
    ms: float | None = None
    """Round trip of the ping in milliseconds (None when down)."""
    server: str | None = None
    """The server process's id (changes when the server restarts)."""
    owned: bool | None = None
    """Whether a client owns the server's arena right now."""
    error: str = ""


class Probe:
    """Pings the server on ``host:port`` (or on ``port`` through ``router``).

    The Zenoh session is opened on the first ping and kept while the server answers; it is
    closed after a failed ping so the next one starts afresh (in client mode ``zenoh.open``
    fails at once when nothing listens, which makes "down" quick to tell).
    """

    def __init__(
        self, host: str, port: int, router: str | None = None, timeout: float = 1.0
    ) -> None:
        self.host, self.port, self.router = WILDCARDS.get(host, host), port, router
        self.timeout = timeout
        self._session: zenoh.Session | None = None
        self._request = encode_request(Ping(), "neuronsmae-probe")

    def ping(self) -> Health:
        """One ping; never raises for an absent, slow or broken server."""
        start = time.perf_counter()
        try:
            if self._session is None:
                self._session = zenoh.open(client_config(self.host, self.port, self.router))
        except zenoh.ZError:
            where = self.router or endpoint(self.host, self.port)
            return Health(self.port, False, error=f"nothing listens on {where}")
        try:
            replies = self._session.get(
                rpc_key(self.port), payload=self._request, timeout=self.timeout
            )
            health = self._read(next(iter(replies), None), start)
        except zenoh.ZError as exc:
            health = Health(self.port, False, error=f"zenoh: {exc}")
        if not health.up:
            self.close()
        return health

    def _read(self, reply: zenoh.Reply | None, start: float) -> Health:
        ms = (time.perf_counter() - start) * 1000.0
        if reply is None:
            return Health(self.port, False, error="no server answers")
        if reply.ok is None:
            detail = reply.err.payload.to_string() if reply.err is not None else "error"
            return Health(self.port, False, error=f"no answer within {self.timeout:g} s: {detail}")
        try:
            decoded = decode_reply(reply.ok.payload.to_bytes())
        except MalformedMessageError as exc:
            return Health(self.port, False, error=f"unreadable reply: {exc}")
        if isinstance(decoded, ErrorReply):
            return Health(self.port, False, ms, error=f"{decoded.code}: {decoded.message}")
        value = decoded.value if isinstance(decoded.value, dict) else {}
        return Health(self.port, True, ms, value.get("server"), value.get("owned"))

    def close(self) -> None:
        """Close the session; safe to call twice."""
        session, self._session = self._session, None
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                session.close()

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
