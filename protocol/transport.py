"""Zenoh session settings shared by the server and the client.

Both ends are pinned to one explicit TCP endpoint with every form of discovery off, so a
server is reachable only where it was told to listen, a client talks only to the server it
named, and two servers on one machine can never find each other (no multicast scouting, no
gossip, no default ``tcp/[::]:0`` listener).

A Zenoh *router* is the one opt-in exception, for clients on other machines: a server may
also connect to routers (``server_config(..., routers=[...])``) and a client may connect to
a router instead of the server (``client_config(..., router=...)``); the query then travels
client → router → server, keyed by ``neuronsmae/<port>/rpc``. See ``deploy/README.md``.

TLS: when the environment variable ``NEURONSMAE_ZENOH_TLS`` names a Zenoh JSON5 file, the
``transport.link.tls`` section of that file (CA, own certificate and key, ``enable_mtls``)
is copied into every session opened here, so servers and clients can reach a router that
accepts mutual TLS only (``deploy/zenoh-router-tls.json5``) at a ``tls/host:port`` locator.
Nothing else of the file is used: endpoints and discovery stay as described above. A file
that cannot be used (missing, unreadable, invalid, no TLS settings) raises
:class:`~neuronsmae.protocol.errors.InvalidOptionError` naming the variable and the file
wherever a configuration is built, and clients check it before launching a server.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence

import zenoh

from neuronsmae.protocol.errors import InvalidOptionError

MAX_BUSY_POLL_US = 100_000.0
"""Longest a server may poll for its next request (``neuronsmae-server --busy-poll``):
beyond a tenth of a second it is a spinning server, not a fast one."""
TLS_ENV = "NEURONSMAE_ZENOH_TLS"
"""Environment variable naming a Zenoh JSON5 file whose ``transport.link.tls`` to use."""


LOCATOR = re.compile(r"[a-z][a-z0-9-]*/\S+")
"""A Zenoh locator: ``<protocol>/<address>``, e.g. ``tcp/10.0.0.1:7447``, ``tls/h:7447``."""


def check_locator(value: object, name: str = "router") -> None:
    """Refuse a router that is not a Zenoh locator before any session is opened (Zenoh's
    own refusal is a configuration parse error naming none of this)."""
    if not isinstance(value, str) or not LOCATOR.fullmatch(value):
        raise InvalidOptionError(
            f"{name} must be a Zenoh locator <protocol>/<address> such as "
            f"tcp/10.0.0.1:7447, got {value!r}"
        )


def check_host(value: object, name: str = "host") -> None:
    """Refuse a host that is not a non-empty name or address without spaces (an empty
    one made the locator ``tcp/:port``, a non-string a TypeError)."""
    if not isinstance(value, str) or not value.strip("[]") or any(c.isspace() for c in value):
        raise InvalidOptionError(
            f"{name} must be a host name or address such as 127.0.0.1 or server.lan, got {value!r}"
        )


def zenoh_message(exc: BaseException) -> str:
    """A Zenoh error's message on one line, without the path into Zenoh's Rust sources it
    appends (`` at /root/.cargo/...``), for messages a user reads."""
    return " ".join(str(exc).split()).split(" at /")[0]


def endpoint(host: str, port: int) -> str:
    """The Zenoh locator of ``host:port`` over TCP (IPv6 literals get brackets)."""
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"tcp/{host}:{port}"


def tls_section() -> str | None:
    """The ``transport.link.tls`` section (as JSON) of the file ``NEURONSMAE_ZENOH_TLS``
    names, or None when the variable is unset or empty.

    Raises :class:`InvalidOptionError` naming the variable and the file when the file
    cannot be used: missing, unreadable, a directory, not a Zenoh configuration, or with
    nothing set under ``transport.link.tls`` (then the variable would change nothing, which
    is never what setting it meant). Zenoh's own refusal (``No such file or directory (os
    error 2)``) names neither, and surfaced as "no server listens" in a client.
    """
    path = os.environ.get(TLS_ENV)
    if not path:
        return None
    valid = (
        "it must name a readable Zenoh configuration file (.json5, .json or .yaml) whose "
        "transport.link.tls section gives this process's CA, certificate and key "
        "(root_ca_certificate, connect_certificate, connect_private_key, enable_mtls), "
        "or be unset for plain TCP; see docs/reliability.md, 'Access'"
    )
    try:
        with open(path, "rb"):
            pass
    except OSError as exc:
        raise InvalidOptionError(
            f"{TLS_ENV}={path!r} cannot be read ({exc.strerror or exc}); {valid}"
        ) from exc
    try:
        tls = zenoh.Config.from_file(path).get_json("transport/link/tls")
    except zenoh.ZError as exc:
        raise InvalidOptionError(
            f"{TLS_ENV}={path!r} is not a valid Zenoh configuration ({zenoh_message(exc)}); {valid}"
        ) from exc
    if tls == zenoh.Config().get_json("transport/link/tls"):
        raise InvalidOptionError(
            f"{TLS_ENV}={path!r} sets nothing under transport.link.tls; {valid}"
        )
    return tls


def check_tls() -> None:
    """Refuse an unusable ``NEURONSMAE_ZENOH_TLS`` file (see :func:`tls_section`) before
    anything is launched: a server started with it would only exit, saying less."""
    tls_section()


def _base_config(mode: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    tls = tls_section()
    if tls is not None:
        conf.insert_json5("transport/link/tls", tls)
    return conf


def server_config(host: str, port: int, routers: Sequence[str] = ()) -> zenoh.Config:
    """A peer that listens on ``tcp/host:port`` only and connects nowhere but ``routers``.

    Routers (Zenoh locators such as ``tcp/10.0.0.1:7447``) let clients that cannot reach
    ``host:port`` query this server through them. A peer keeps retrying a router that is
    not up yet, so servers and router may start in any order. Raises InvalidOptionError
    for an unusable ``NEURONSMAE_ZENOH_TLS`` file (:func:`tls_section`).
    """
    conf = _base_config("peer")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint(host, port)]))
    conf.insert_json5("connect/endpoints", json.dumps(list(routers)))
    return conf


def client_config(host: str, port: int, router: str | None = None) -> zenoh.Config:
    """A client that connects to ``tcp/host:port`` only (or to ``router`` only) and listens
    nowhere.

    In client mode ``zenoh.open`` fails at once when nothing listens there (which is how
    the client knows to launch a server) and, once open, the session reconnects by itself
    when a server comes back on that endpoint. Raises InvalidOptionError for an unusable
    ``NEURONSMAE_ZENOH_TLS`` file (:func:`tls_section`).
    """
    conf = _base_config("client")
    target = router or endpoint(host, port)
    conf.insert_json5("connect/endpoints", json.dumps([target]))
    conf.insert_json5("listen/endpoints", "[]")
    # Retry a lost server every 0.25 s at first and at least every second (Zenoh's default
    # backs off to 4 s), so a restarted server is found again soon after it listens.
    retry = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
    conf.insert_json5("connect/retry", json.dumps(retry))
    return conf
