"""Zenoh session settings shared by the server and the client.

Both ends are pinned to one explicit TCP endpoint with every form of discovery off, so a
server is reachable only where it was told to listen, a client talks only to the server it
named, and two servers on one machine can never find each other (no multicast scouting, no
gossip, no default ``tcp/[::]:0`` listener).
"""

from __future__ import annotations

import json

import zenoh


def endpoint(host: str, port: int) -> str:
    """The Zenoh locator of ``host:port`` over TCP (IPv6 literals get brackets)."""
    if ":" in host and not host.startswith("["):
        host = f"[{host}]"
    return f"tcp/{host}:{port}"


def _base_config(mode: str) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


def server_config(host: str, port: int) -> zenoh.Config:
    """A peer that listens on ``tcp/host:port`` only and connects nowhere."""
    conf = _base_config("peer")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint(host, port)]))
    conf.insert_json5("connect/endpoints", "[]")
    return conf


def client_config(host: str, port: int) -> zenoh.Config:
    """A client that connects to ``tcp/host:port`` only and listens nowhere.

    In client mode ``zenoh.open`` fails at once when nothing listens there (which is how
    the client knows to launch a server) and, once open, the session reconnects by itself
    when a server comes back on that endpoint.
    """
    conf = _base_config("client")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint(host, port)]))
    conf.insert_json5("listen/endpoints", "[]")
    # Retry a lost server every 0.25 s at first and at least every second (Zenoh's default
    # backs off to 4 s), so a restarted server is found again soon after it listens.
    retry = {"period_init_ms": 250, "period_max_ms": 1000, "period_increase_factor": 2}
    conf.insert_json5("connect/retry", json.dumps(retry))
    return conf
