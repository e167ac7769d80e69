"""One client's connection to one server: find or launch it, claim it, send requests.

``RM`` (one arena) and ``VecRM`` (many, over one or several servers) both talk to each
server through a :class:`Connection`:

* **Where.** ``port=None`` launches a private server on a free loopback port, stopped on
  :meth:`Connection.close`, so any number of clients run side by side. An explicit port
  connects to the server there, or launches one on it when nothing listens on a local host.
* **Claim.** ``configure`` (seed, options, arena count) is sent at once and again whenever
  the server answers ``not_configured`` (it restarted); the request is then retried once.
* **Requests.** :meth:`call` waits for the reply; :meth:`send` returns a :class:`Call` at
  once, so requests to several servers are in flight together. Every request waits at most
  ``timeout`` seconds; no reply raises ``ServerUnavailableError``.
"""

from __future__ import annotations

import uuid
import weakref
from collections.abc import Callable

from neuronsmae.protocol.defaults import DEFAULT_HOST
from neuronsmae.protocol.errors import (
    InvalidOptionError,
    MalformedMessageError,
    MessageTooLargeError,
    NeuronsMAEError,
    ServerError,
    ServerUnavailableError,
    error_from_code,
)
from neuronsmae.protocol.launch import (
    PORT_IN_USE_STATUS,
    ServerCommand,
    ServerProcess,
    check_timeout,
    is_local,
    launch_private,
    ports_of,
)
from neuronsmae.protocol.link import Link, Pending
from neuronsmae.protocol.messages import (
    MAX_REQUEST_BYTES,
    NOT_CONFIGURED,
    Close,
    Configure,
    ErrorReply,
    Message,
    OkReply,
    Ping,
    Reply,
    decode_reply,
    encode_request,
)
from neuronsmae.protocol.transport import check_host, check_locator, check_tls

CLOSE_TIMEOUT = 1.0
"""Seconds ``close`` waits for the server to acknowledge, so closing never hangs."""
PROBE_TIMEOUT = 1.0
"""Seconds each readiness ping of a starting server may take."""


def _shutdown(link: Link, server: ServerProcess | None, farewell: bytes) -> None:
    """Release the server and the session (runs once, from close() or garbage collection)."""
    try:
        if server is None:
            link.call(farewell, CLOSE_TIMEOUT)
    except NeuronsMAEError:
        pass  # the server is gone or busy: nothing left to release
    finally:
        link.close()
        if server is not None:
            server.stop()


def answering_pid(link: Link, session: str = "", timeout: float = PROBE_TIMEOUT) -> int | None:
    """The pid of the server answering a ping on ``link`` now, None while none answers
    (used while a server starts, to tell the one launched from any other). A session that
    cannot even be configured (an unusable ``NEURONSMAE_ZENOH_TLS`` file) raises its
    InvalidOptionError: that is no "not answering yet"."""
    try:
        reply = decode_reply(link.call(encode_request(Ping(), session), timeout))
    except InvalidOptionError:
        raise
    except NeuronsMAEError:
        return None
    value = reply.value if isinstance(reply, OkReply) else None
    pid = value.get("pid") if isinstance(value, dict) else None
    return pid if isinstance(pid, int) else None


class Call:
    """A request in flight on one connection; :meth:`result` gives its reply."""

    def __init__(
        self,
        conn: Connection,
        data: bytes,
        pending: Pending,
        bad_input: type[NeuronsMAEError],
    ) -> None:
        self._conn, self._data, self._pending, self._bad_input = conn, data, pending, bad_input

    def result(self) -> OkReply:
        """The reply, or the server's error raised as its type."""
        reply = self._conn._decode(self._pending.result())
        if isinstance(reply, ErrorReply) and reply.code == NOT_CONFIGURED:
            self._conn.configure()  # the server restarted: claim it again, then retry once
            reply = self._conn._decode(self._conn.link.call(self._data, self._conn.timeout))
        if isinstance(reply, ErrorReply):
            raise error_from_code(reply.code, reply.message)
        return reply


class Connection:
    """A session with one server, launched by this client when there was none."""

    def __init__(
        self,
        *,
        port: int | None,
        command: Callable[[int], ServerCommand],
        configure: Configure,
        host: str = DEFAULT_HOST,
        router: str | None = None,
        launch: bool = True,
        timeout: float = 10.0,
    ) -> None:
        if port is not None:
            ports_of(port)  # one port in 1..65535, or InvalidOptionError
        check_timeout(timeout)
        check_host(host)
        if router is not None:
            check_locator(router)
        check_tls()  # a bad NEURONSMAE_ZENOH_TLS file: said now, not as "no server listens"
        self.host, self.router, self.timeout = host, router, float(timeout)
        self.session_id = uuid.uuid4().hex
        self.server: ServerProcess | None = None
        self._configure_body = configure
        self._closer: weakref.finalize | None = None
        self.link = Link(host, port or 0, router)
        try:
            if port is None:
                self._launch_private(command)
            else:
                self._connect(port, command, launch)
            farewell = encode_request(Close(), self.session_id)
            self._closer = weakref.finalize(self, _shutdown, self.link, self.server, farewell)
            self.configured = self.configure()
            """The ``configure`` reply: protocol ``version``, ``server`` id, ``arenas``."""
        except BaseException:
            self.close()
            raise

    @property
    def port(self) -> int:
        return self.link.port

    # ---- finding the server ------------------------------------------------------------

    def _launch_private(self, command: Callable[[int], ServerCommand]) -> None:
        if self.router:
            raise ServerUnavailableError("a private server cannot be reached through a router")
        if not is_local(self.host):
            raise ServerUnavailableError(
                f"no port given and {self.host} is not this machine: private servers are "
                "launched on this machine only; give the port of a running server"
            )
        links: dict[int, Link] = {}

        def ready(port: int) -> int | None:
            link = links.setdefault(port, Link(self.host, port))
            return answering_pid(link, self.session_id)

        try:
            self.server = launch_private(command, ready, self.host)
            self.link = links.pop(self.server.port)
        finally:
            for link in links.values():
                link.close()

    def _connect(self, port: int, command: Callable[[int], ServerCommand], launch: bool) -> None:
        if self.link.open():
            return
        where = self.link.where
        if self.router:
            raise ServerUnavailableError(f"cannot reach the Zenoh router for {where}")
        if not launch:
            raise ServerUnavailableError(f"no server listens on {where} (launch=False)")
        if not is_local(self.host):
            raise ServerUnavailableError(
                f"no server listens on {where}; servers are only launched on this machine"
            )
        server = ServerProcess(command(port))
        try:
            server.wait_ready(lambda: answering_pid(self.link, self.session_id))
        except ServerUnavailableError:
            server.stop()
            lost_the_bind = server.exited() == PORT_IN_USE_STATUS
            if not (lost_the_bind and answering_pid(self.link, self.session_id) is not None):
                raise
            return  # another server took the port meanwhile: connect to it, as to any
        self.server = server

    # ---- requests ----------------------------------------------------------------------

    def configure(self) -> dict[str, object]:
        """Claim the server with this client's seed, options and arena count."""
        value = self.call(self._configure_body, InvalidOptionError).value
        return value if isinstance(value, dict) else {}

    def send(self, body: Message, bad_input: type[NeuronsMAEError] = MalformedMessageError) -> Call:
        """Send ``body`` and return at once; ``bad_input`` is raised when the arguments
        cannot even be encoded (the type the in-process arena raises for them)."""
        if self._closer is not None and not self._closer.alive:
            raise ServerUnavailableError(f"this client of {self.link.where} is closed")
        try:
            data = encode_request(body, self.session_id)
        except MalformedMessageError as exc:
            raise bad_input(str(exc)) from exc
        if len(data) > MAX_REQUEST_BYTES:
            raise MessageTooLargeError(
                f"request of {len(data)} bytes exceeds the limit of {MAX_REQUEST_BYTES}"
            )
        return Call(self, data, self.link.send(data, self.timeout), bad_input)

    def call(
        self, body: Message, bad_input: type[NeuronsMAEError] = MalformedMessageError
    ) -> OkReply:
        """Send ``body`` and wait for the reply (or raise the server's error as its type)."""
        return self.send(body, bad_input).result()

    def _decode(self, raw: bytes) -> Reply:
        try:
            return decode_reply(raw)
        except MalformedMessageError as exc:
            raise ServerError(f"unreadable reply from {self.link.where}: {exc}") from exc

    def close(self) -> None:
        """Give the server back (or stop it if this client launched it); safe to repeat."""
        if self._closer is not None:
            self._closer()  # releases the server once; later calls do nothing
        else:  # construction failed before the finalizer existed
            self.link.close()
            if self.server is not None:
                self.server.stop()
