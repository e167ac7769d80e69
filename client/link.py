"""The client's Zenoh connection: one query out, one reply back, within a timeout.

The session is opened lazily and kept: in client mode Zenoh reconnects by itself when a
server comes back on the same endpoint, so a dead server only ever shows up here as "no
reply", which :meth:`Link.call` turns into :class:`ServerUnavailableError`.
"""

from __future__ import annotations

import contextlib

import zenoh

from neuronsmae.protocol.errors import ServerUnavailableError
from neuronsmae.protocol.messages import rpc_key
from neuronsmae.protocol.transport import client_config, endpoint


class Link:
    """A lazily opened Zenoh client session bound to one server's queryable."""

    def __init__(self, host: str, port: int, router: str | None = None) -> None:
        self.host, self.port, self.router = host, port, router
        self.where = (
            f"{rpc_key(port)} via router {router}"
            if router
            else f"{endpoint(host, port)} ({rpc_key(port)})"
        )
        self._key = rpc_key(port)
        self._session: zenoh.Session | None = None
        self._queriers: dict[float, zenoh.Querier] = {}

    def open(self) -> bool:
        """Open the session if needed; False when nothing listens on the endpoint (or the
        router, when there is one: then only a query tells whether the server is there)."""
        if self._session is None:
            try:
                self._session = zenoh.open(client_config(self.host, self.port, self.router))
            except zenoh.ZError:
                return False
        return True

    def _querier(self, timeout: float) -> zenoh.Querier:
        """One querier per timeout value: declared once, reused for every call."""
        querier = self._queriers.get(timeout)
        if querier is None:
            assert self._session is not None
            querier = self._session.declare_querier(
                self._key,
                timeout=timeout,
                consolidation=zenoh.ConsolidationMode.NONE,
                target=zenoh.QueryTarget.BEST_MATCHING,
                express=True,  # sent at once, never held back to batch with others
            )
            self._queriers[timeout] = querier
        return querier

    def call(self, payload: bytes, timeout: float) -> bytes:
        """Send one request and return the reply's bytes.

        Raises ServerUnavailableError when nothing listens, nothing answers before
        ``timeout`` seconds, or the server is gone (Zenoh then ends the query at once).
        """
        if not self.open():
            raise ServerUnavailableError(f"no server listens on {self.where}")
        try:
            for reply in self._querier(timeout).get(payload=payload):
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
                # The server never replies with errors itself: this one comes from Zenoh,
                # such as "Timeout" when the server took longer than ``timeout``.
                err = reply.err
                detail = err.payload.to_string() if err is not None else "unknown error"
                raise ServerUnavailableError(
                    f"no answer from {self.where} within {timeout:g} s ({detail})"
                )
        except zenoh.ZError as exc:
            raise ServerUnavailableError(f"query to {self.where} failed: {exc}") from exc
        raise ServerUnavailableError(f"no NeuronsMAE server answers on {self.where}")

    def close(self) -> None:
        """Close the session; safe to call twice."""
        queriers, self._queriers = self._queriers, {}
        session, self._session = self._session, None
        for querier in queriers.values():
            with contextlib.suppress(zenoh.ZError):
                querier.undeclare()
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                session.close()
