"""Loopback ports for tests that start servers or routers on a port they choose.

They come from :data:`bench.common.PORT_BLOCK`, below the kernel's ephemeral range and
above Ray's worker ports: a port the kernel hands out for an outgoing connection (Ray opens
many) can never land there between the check and the server's bind, which made tests that
took ``base`` and ``base + 1`` from the ephemeral range fail now and then. On a machine
whose ephemeral range covers the block, :func:`free_ports` fails loudly rather than flakily.
"""

from __future__ import annotations

from bench.common import PORT_BLOCK, free_ports, port_is_free

__all__ = ["PORT_BLOCK", "free_port", "free_ports", "port_is_free"]


def free_port() -> int:
    """One loopback port in :data:`PORT_BLOCK` that is free right now."""
    return free_ports(1)
