"""Zenoh endpoints given on a command line, checked before anything starts.

:func:`neuronsmae.protocol.transport.check_locator` checks a locator's shape
(``<protocol>/<address>``); Zenoh itself checks an IP endpoint's port only when a session
opens. For a router a server or fleet connects to, that is never said at all: the peer
keeps retrying an endpoint it cannot parse, so ``--router tcp/127.0.0.1:99999`` gave a
server that started, logged nothing and was reachable by no client. :func:`check_endpoint`
adds the port check for the protocols whose address is ``host:port``. Kept apart from
:mod:`neuronsmae.server.serving.rpc` so ``deploy/run_router.py`` can use it without importing
the arena.
"""

from __future__ import annotations

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.transport import check_locator

HOST_PORT_PROTOCOLS = frozenset({"tcp", "udp", "tls", "quic", "ws"})
"""Zenoh link protocols whose address is ``host:port`` (others, such as
``unixsock-stream/<path>``, are left to Zenoh)."""
MAX_PORT = 65535


def check_endpoint(value: object, name: str = "router", *, listen: bool = False) -> None:
    """Raise InvalidOptionError naming ``name`` unless ``value`` is a Zenoh locator and, for
    a ``host:port`` protocol, has a host and a port in 1..65535 (0..65535 with ``listen``:
    port 0 asks for any free port)."""
    check_locator(value, name)
    assert isinstance(value, str)  # check_locator refused anything else
    protocol, _, address = value.partition("/")
    if protocol not in HOST_PORT_PROTOCOLS:
        return
    address = address.split("#", 1)[0].split("?", 1)[0]  # Zenoh's config and metadata parts
    host, colon, port = address.rpartition(":")
    lowest = 0 if listen else 1
    if colon and host.strip("[]") and port.isdigit() and lowest <= int(port) <= MAX_PORT:
        return
    raise InvalidOptionError(
        f"{name} must be a Zenoh locator {protocol}/<host>:<port> with a port in "
        f"{lowest}..{MAX_PORT}, such as {protocol}/10.0.0.1:7447, got {value!r}"
    )
