"""Helpers for the deployment tests: free loopback ports and processes that always stop."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests.ports import free_ports as free_ports  # re-exported for the deploy tests

REPO = Path(__file__).resolve().parents[2]
ROUTER_SCRIPT = REPO / "deploy" / "run_router.py"


TEST_PORTS = range(28000, 29000)
"""Where the tests of the fleet's state file and the router's defaults take their ports: a
block of its own on a shared machine, apart from :data:`tests.ports.PORT_BLOCK` that the
other tests draw from."""


def free_test_ports(count: int = 1) -> int:
    """The first of ``count`` consecutive loopback ports in :data:`TEST_PORTS` that are
    free right now, from a random start so that concurrent runs rarely meet."""
    return free_ports(count, TEST_PORTS)


def wait_for(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    """Poll ``predicate`` every 0.2 s until it holds; fail the test after ``timeout``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.2)
    pytest.fail(f"timed out after {timeout:g} s waiting for {what}")


def listening(port: int) -> bool:
    """Whether something accepts TCP connections on 127.0.0.1:``port``."""
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex(("127.0.0.1", port)) == 0


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator[Callable[..., subprocess.Popen[bytes]]]:
    """Start a command (output to a log file in tmp_path, ``env`` added to the environment);
    every one is stopped at the end."""
    started: list[subprocess.Popen[bytes]] = []

    def start(
        *cmd: str, name: str = "proc", env: dict[str, str] | None = None
    ) -> subprocess.Popen[bytes]:
        with (tmp_path / f"{name}-{len(started)}.log").open("wb") as log:
            proc = subprocess.Popen(
                [sys.executable, *cmd],
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=log,
                env=None if env is None else {**os.environ, **env},
            )
        started.append(proc)
        return proc

    yield start
    for proc in started:
        stop(proc)


def stop(proc: subprocess.Popen[bytes], sig: int = signal.SIGTERM, timeout: float = 15) -> int:
    """Signal ``proc`` and wait for it (SIGKILL if it lingers); return its exit status."""
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def server_cmd(port: int, *extra: str) -> list[str]:
    """``python -m neuronsmae.server`` on ``port``, unpaced, tied to this test process."""
    return [
        "-m", "neuronsmae.server", "--port", str(port), "--time-scale", "0",
        "--watch-parent", str(os.getpid()), *extra,
    ]  # fmt: skip
