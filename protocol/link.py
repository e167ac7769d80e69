"""One Zenoh query out, one reply back, within a timeout: the only query code of the project.

The client (``RM``, ``VecRM``) and the server side's supervisor (its pings) both reach a
server through :class:`Link`. The session is opened lazily and kept: in client mode Zenoh
reconnects by itself when a server comes back on the same endpoint, so a dead server only
ever shows up here as "no reply", which :meth:`Link.call` turns into
:class:`~neuronsmae.protocol.errors.ServerUnavailableError`.

Two guards keep a client from hanging:

* **Every open is bounded.** ``zenoh.open`` runs in a helper thread that is given
  ``open_timeout`` seconds; in client mode it fails at once when nothing listens, and the
  bound covers the cases where it would not (an unreachable host that drops packets).
* **Fork safety.** Zenoh's runtime threads do not survive ``fork``: a session opened in a
  child forked from a process that had used Zenoh waits forever. Once this process has
  opened a session, a forked child (``multiprocessing``'s and Gymnasium's ``AsyncVectorEnv``'s
  default ``fork`` context) gets :class:`~neuronsmae.protocol.errors.ForkedZenohError` at
  once from :meth:`Link.open` instead. A child forked before any session was opened is
  fine: the session is opened lazily, in the child.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Iterator

import zenoh

from neuronsmae.protocol.errors import ForkedZenohError, ServerUnavailableError
from neuronsmae.protocol.messages import rpc_key
from neuronsmae.protocol.transport import client_config, endpoint, zenoh_message

OPEN_TIMEOUT = 10.0
"""Seconds ``zenoh.open`` may take before the server counts as unreachable."""

_used_zenoh = False
"""Whether this process has opened a Zenoh session (its runtime threads then exist)."""
_forked_after_use = False
"""Whether this process is a fork of one that had: its Zenoh runtime is unusable."""


def _after_fork_in_child() -> None:
    global _forked_after_use
    _forked_after_use = _forked_after_use or _used_zenoh


os.register_at_fork(after_in_child=_after_fork_in_child)


def check_fork_safe() -> None:
    """Raise :class:`ForkedZenohError` in a child forked from a process that had opened a
    Zenoh session (no session can work there); do nothing anywhere else."""
    if _forked_after_use:
        raise ForkedZenohError(
            "this process was forked from one that had opened a Zenoh session, and Zenoh "
            "does not survive fork: create the NeuronsMAE client in a spawned process "
            "(multiprocessing context 'spawn'; gymnasium.vector.AsyncVectorEnv(..., "
            "context='spawn'), gymnasium.make_vec(..., vectorization_mode='async', "
            "vector_kwargs={'context': 'spawn'})) or before the parent opens any session"
        )


def open_session(config: zenoh.Config, timeout: float = OPEN_TIMEOUT) -> zenoh.Session:
    """``zenoh.open(config)`` within ``timeout`` seconds, refused in a forked child.

    Raises :class:`ForkedZenohError`, ``zenoh.ZError`` (Zenoh refused: nothing listens,
    the port is taken) or :class:`ServerUnavailableError` (no answer in time).
    """
    global _used_zenoh
    check_fork_safe()
    box: dict[str, object] = {}

    def run() -> None:
        try:
            box["session"] = zenoh.open(config)
        except BaseException as exc:  # handed to the caller's thread below
            box["error"] = exc

    thread = threading.Thread(target=run, name="zenoh-open", daemon=True)
    thread.start()
    thread.join(timeout)
    if thread.is_alive():
        raise ServerUnavailableError(f"opening a Zenoh session took more than {timeout:g} s")
    _used_zenoh = True
    if "error" in box:
        raise box["error"]  # type: ignore[misc]
    return box["session"]  # type: ignore[return-value]


class Pending:
    """A request in flight: :meth:`result` waits for its reply (see :meth:`Link.send`)."""

    def __init__(self, link: Link, replies: Iterator[zenoh.Reply], timeout: float) -> None:
        self._link, self._replies, self._timeout = link, replies, timeout

    def result(self) -> bytes:
        """The reply's bytes; raises ServerUnavailableError like :meth:`Link.call`."""
        where, timeout = self._link.where, self._timeout
        try:
            for reply in self._replies:
                if reply.ok is not None:
                    return reply.ok.payload.to_bytes()
                # The server never replies with errors itself: this one comes from Zenoh,
                # such as "Timeout" when the server took longer than ``timeout``.
                err = reply.err
                detail = err.payload.to_string() if err is not None else "unknown error"
                raise ServerUnavailableError(
                    f"no answer from {where} within {timeout:g} s ({detail})"
                )
        except zenoh.ZError as exc:
            raise ServerUnavailableError(f"query to {where} failed: {zenoh_message(exc)}") from exc
        raise ServerUnavailableError(f"no NeuronsMAE server answers on {where}")


class Link:
    """A lazily opened Zenoh client session bound to one server's queryable."""

    def __init__(
        self,
        host: str,
        port: int,
        router: str | None = None,
        open_timeout: float = OPEN_TIMEOUT,
    ) -> None:
        self.host, self.port, self.router = host, port, router
        self.open_timeout = open_timeout
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
        router, when there is one: then only a query tells whether the server is there).

        Raises :class:`ForkedZenohError` in a child forked after this process used Zenoh,
        and :class:`~neuronsmae.protocol.errors.InvalidOptionError` when the
        ``NEURONSMAE_ZENOH_TLS`` file cannot be used: the configuration is built outside the
        "nothing listens" handling, since a bad file is not an absent server.
        """
        if self._session is None:
            config = client_config(self.host, self.port, self.router)
            try:
                self._session = open_session(config, self.open_timeout)
            except (zenoh.ZError, ServerUnavailableError):
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

    def send(self, payload: bytes, timeout: float) -> Pending:
        """Send one request and return at once; ``result()`` waits for the reply. Requests
        to several servers are then in flight at the same time."""
        if not self.open():
            raise ServerUnavailableError(f"no server listens on {self.where}")
        try:
            replies = self._querier(timeout).get(payload=payload)
        except zenoh.ZError as exc:
            raise ServerUnavailableError(
                f"query to {self.where} failed: {zenoh_message(exc)}"
            ) from exc
        return Pending(self, iter(replies), timeout)

    def call(self, payload: bytes, timeout: float) -> bytes:
        """Send one request and return the reply's bytes.

        Raises ServerUnavailableError when nothing listens, nothing answers before
        ``timeout`` seconds, or the server is gone (Zenoh then ends the query at once).
        """
        return self.send(payload, timeout).result()

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
