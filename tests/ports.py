"""Loopback ports for tests that start servers or routers on a port they choose.

The ports come from :data:`TEST_PORTS`, below the kernel's ephemeral range (32768–60999
on Linux) and above Ray's worker ports (10002–19999): a port the kernel hands out for an
outgoing connection (Ray opens many) can never land there between the check and the
server's bind, which made tests that took ``base`` and ``base + 1`` from the ephemeral
range fail now and then.
"""

from __future__ import annotations

import random
import socket

TEST_PORTS = range(24000, 28000)
"""Where the tests' servers and routers listen (the fleet state-file tests keep their own
block, ``tests/deploy/conftest.TEST_PORTS``)."""


def is_free(port: int) -> bool:
    """Nothing is bound to ``port`` on loopback right now."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_ports(count: int = 1, ports: range = TEST_PORTS) -> int:
    """The first of ``count`` consecutive loopback ports in ``ports`` that are free right
    now, from a random start so that concurrent test runs rarely meet."""
    starts = list(ports[: len(ports) - count + 1])
    offset = random.randrange(len(starts))
    for base in starts[offset:] + starts[:offset]:
        if all(is_free(base + i) for i in range(count)):
            return base
    raise RuntimeError(f"no {count} consecutive free ports in {ports}")


def free_port() -> int:
    """One loopback port in :data:`TEST_PORTS` that is free right now."""
    return free_ports(1)
