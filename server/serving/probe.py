"""Ping a server through the protocol's ``ping`` message, as a supervisor needs it.

The fleet launcher (:mod:`neuronsmae.server.serving.fleet`) must tell whether each server
answers. It reaches them through the protocol's one query helper
(:class:`~neuronsmae.protocol.link.Link`), and reports a :class:`Health` record instead of
an exception, because for a supervisor "down" is an answer, not an error.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

from neuronsmae.protocol.errors import MalformedMessageError, NeuronsMAEError
from neuronsmae.protocol.launch import check_timeout
from neuronsmae.protocol.link import Link
from neuronsmae.protocol.messages import ErrorReply, Ping, decode_reply, encode_request

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
    """Pings the server on ``host:port`` (or on ``port`` through ``router``), waiting up to
    ``timeout`` seconds for each answer (InvalidOptionError unless finite and > 0).

    The session is opened on the first ping and kept while the server answers; it is
    closed after a failed ping so the next one starts afresh (in client mode a session
    fails at once when nothing listens, which makes "down" quick to tell).
    """

    def __init__(
        self, host: str, port: int, router: str | None = None, timeout: float = 1.0
    ) -> None:
        check_timeout(timeout, "ping timeout")
        self.port, self.timeout = port, timeout
        self._link = Link(WILDCARDS.get(host, host), port, router)
        self._request = encode_request(Ping(), "neuronsmae-probe")

    def ping(self) -> Health:
        """One ping; never raises for an absent, slow or broken server."""
        start = time.perf_counter()
        try:
            raw = self._link.call(self._request, self.timeout)
            decoded = decode_reply(raw)
        except MalformedMessageError as exc:
            health = Health(self.port, False, error=f"unreadable reply: {exc}")
        except NeuronsMAEError as exc:
            health = Health(self.port, False, error=str(exc))
        else:
            ms = (time.perf_counter() - start) * 1000.0
            if isinstance(decoded, ErrorReply):
                health = Health(self.port, False, ms, error=f"{decoded.code}: {decoded.message}")
            else:
                value = decoded.value if isinstance(decoded.value, dict) else {}
                health = Health(self.port, True, ms, value.get("server"), value.get("owned"))
        if not health.up:
            self.close()
        return health

    def close(self) -> None:
        """Close the session; safe to call twice."""
        self._link.close()

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
