"""The Zenoh half of the server: one queryable, answered from the main thread.

Why the main thread: the arena (PyBullet, numba) is not thread-safe and every request must
see the state the previous one left, so requests are taken one at a time from the
queryable's FIFO channel and answered in order. ``Queryable.recv`` polls for signals while
it blocks, which is how SIGTERM/SIGINT reach :class:`StopSignal` promptly.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import signal
import socket
import threading
import time
from collections.abc import Iterator, Sequence
from types import FrameType

import zenoh

from neuronsmae.protocol.errors import InvalidOptionError, MessageTooLargeError, NeuronsMAEError
from neuronsmae.protocol.messages import MAX_REQUEST_BYTES, ErrorReply, encode_reply, rpc_key
from neuronsmae.protocol.transport import endpoint, server_config
from neuronsmae.server.serving.service import ArenaService

log = logging.getLogger("neuronsmae.server")


class PortInUseError(NeuronsMAEError, OSError):
    """The server's TCP port is taken by another process."""

    code = "port_in_use"


class Interrupted(BaseException):
    """Raised by the signal handler to leave a blocking wait; not an error."""


class StopSignal:
    """Turns SIGTERM/SIGINT into an orderly stop.

    While a request is being answered (:meth:`critical`) a signal only sets
    :attr:`requested`, so the reply still goes out and the arena is never left mid-step;
    anywhere else (blocked in ``recv``, building the arena at startup) it raises
    :class:`Interrupted` to return at once.
    """

    def __init__(self) -> None:
        self.requested = False
        self._interruptible = True

    def install(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, self._handler)

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        log.info("received %s, shutting down", signal.Signals(signum).name)
        self.requested = True
        if self._interruptible:
            raise Interrupted

    @contextlib.contextmanager
    def critical(self) -> Iterator[None]:
        self._interruptible = False
        try:
            yield
        finally:
            self._interruptible = True


def _bind_probe(host: str, port: int) -> None:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        probe.bind((host.strip("[]"), port))


def check_listen_host(host: object, name: str = "host") -> None:
    """Raise InvalidOptionError unless ``host`` is an address of this machine a server can
    listen on (a name that resolves to one counts; ``0.0.0.0`` means every address).

    Why check first: Zenoh reports such a host only once the arenas are built, as a bare
    ``Name or service not known`` (or a parse error, for an empty host) naming no argument.
    """
    examples = "such as 127.0.0.1 (0.0.0.0: every address)"
    if not isinstance(host, str) or not host.strip("[]"):
        raise InvalidOptionError(
            f"{name} must be an address of this machine {examples}, got {host!r}"
        )
    try:
        _bind_probe(host, 0)
    except socket.gaierror as exc:
        raise InvalidOptionError(
            f"{name} {host!r} does not resolve ({exc.strerror}); give an address of this "
            f"machine {examples}"
        ) from exc
    except OSError as exc:
        if exc.errno == errno.EADDRNOTAVAIL:
            raise InvalidOptionError(
                f"{name} {host!r} is not an address of this machine; give one of its own {examples}"
            ) from exc
        raise


def check_port(host: str, port: int) -> None:
    """Raise PortInUseError if something already listens on ``host:port`` (``host`` already
    checked by :func:`check_listen_host`).

    Zenoh's own bind failure is caught too (see :class:`RpcServer`); checking first gives a
    clear message before the slow arena build rather than after it. SO_REUSEADDR makes the
    probe ignore connections lingering in TIME_WAIT, so only a live listener counts.
    """
    try:
        _bind_probe(host, port)
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise PortInUseError(f"port {port} on {host} is already in use") from exc
        raise


def watch_parent(parent_pid: int, period: float = 0.25) -> None:
    """SIGTERM this process when ``parent_pid`` is gone, so a launched server never outlives
    the client that launched it (even if that client is killed without closing)."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(period)
        log.info("parent process %d exited", parent_pid)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="watch-parent", daemon=True).start()


def next_query(queryable: zenoh.Queryable, busy_poll_s: float = 0.0) -> zenoh.Query:
    """The next request, polled for up to ``busy_poll_s`` seconds before blocking on it.

    Why poll: a blocked thread on an idle core is woken slowly (on a 2-core VM the request
    reaches a polling server about 90 µs sooner), and a trainer's next request usually
    comes within a millisecond of the last reply. The price is a core kept busy for that
    long after every reply, which only pays when a core is spare: one server per client
    with cores to spare, not many servers sharing a few cores.
    """
    if busy_poll_s > 0:
        deadline = time.perf_counter() + busy_poll_s
        while time.perf_counter() < deadline:
            query = queryable.try_recv()
            if query is not None:
                return query
    return queryable.recv()


class RpcServer:
    """Serves an :class:`ArenaService` on ``neuronsmae/<port>/rpc`` at ``tcp/host:port``."""

    def __init__(
        self,
        service: ArenaService,
        host: str,
        port: int,
        stop: StopSignal,
        routers: Sequence[str] = (),
        busy_poll_s: float = 0.0,
    ) -> None:
        self.service = service
        self.host, self.port = host, port
        self.routers = tuple(routers)
        """Zenoh routers to connect to as well, for clients that cannot reach host:port."""
        self.busy_poll_s = busy_poll_s
        """Seconds to poll for the next request before blocking (see :func:`next_query`)."""
        self.key = rpc_key(port)
        self._stop = stop
        self._session: zenoh.Session | None = None
        self._queryable: zenoh.Queryable | None = None

    def __enter__(self) -> RpcServer:
        try:
            self._session = zenoh.open(server_config(self.host, self.port, self.routers))
        except zenoh.ZError as exc:
            if "in use" in str(exc):
                raise PortInUseError(f"port {self.port} on {self.host} is already in use") from exc
            raise
        try:
            self._queryable = self._session.declare_queryable(self.key)
        except BaseException:
            self.close()
            raise
        log.info("serving %s on %s", self.key, endpoint(self.host, self.port))
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Undeclare and close the session; safe to call twice."""
        queryable, self._queryable = self._queryable, None
        session, self._session = self._session, None
        if queryable is not None:
            with contextlib.suppress(zenoh.ZError):
                queryable.undeclare()
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                session.close()

    def serve_forever(self) -> None:
        """Answer queries until a stop signal arrives."""
        assert self._queryable is not None, "use RpcServer as a context manager"
        queryable = self._queryable
        try:
            while not self._stop.requested:
                query = next_query(queryable, self.busy_poll_s)
                with self._stop.critical(), query:
                    self._answer(query)
        except Interrupted:
            pass

    def _answer(self, query: zenoh.Query) -> None:
        payload = query.payload
        if payload is not None and len(payload) > MAX_REQUEST_BYTES:
            error = MessageTooLargeError(
                f"request of {len(payload)} bytes exceeds the limit of {MAX_REQUEST_BYTES}"
            )
            reply = encode_reply(ErrorReply.from_exception(error))
        else:
            reply = self.service.handle(payload.to_bytes() if payload is not None else b"")
        try:
            query.reply(self.key, reply, express=True)  # one RPC reply: never batched
        except zenoh.ZError as exc:  # the querier gave up (timeout) or went away
            log.debug("reply not delivered: %s", exc)
