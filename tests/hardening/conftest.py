"""Hardening tests reuse the client tests' real-server helpers (subprocess servers on free
loopback ports, scouting off), so both suites start servers the same way."""

from __future__ import annotations

from tests.client.conftest import RawClient, Server, free_port, same, start_server

__all__ = ["RawClient", "Server", "free_port", "same", "start_server"]
