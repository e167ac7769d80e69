"""Real servers on loopback ports, started as subprocesses, shared per test module."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import zenoh

from bench.common import same as same
from neuronsmae.client import answering_pid
from neuronsmae.protocol.messages import Reply, decode_reply, rpc_key
from neuronsmae.protocol.transport import client_config
from neuronsmae.server.arena import Arena
from neuronsmae.server.serving.service import warm_up
from tests.ports import free_port as free_port  # re-exported: the tests import both here

STARTUP_TIMEOUT = 120.0


class Server:
    """A ``python -m neuronsmae.server`` subprocess on one port."""

    def __init__(self, port: int, *args: str) -> None:
        self.port = port
        cmd = [sys.executable, "-m", "neuronsmae.server", "--port", str(port), *args]
        cmd += ["--watch-parent", str(os.getpid())]  # no orphans if the test run is killed
        # A file, not a pipe, so a chatty server never blocks; closed in stop().
        self.log = tempfile.TemporaryFile()  # noqa: SIM115
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self.log
        )

    def stderr(self) -> str:
        self.log.seek(0)
        return self.log.read().decode(errors="replace")

    def wait_ready(self, timeout: float = STARTUP_TIMEOUT) -> Server:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.stderr()}")
            if answering_pid(self.port) == self.proc.pid:  # this server, not one on its port
                return self
            time.sleep(0.1)
        raise RuntimeError(f"server on port {self.port} did not start")

    def stop(self, sig: int = signal.SIGTERM) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGCONT)  # in case a test left it stopped
            self.proc.send_signal(sig)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.log.close()
        return self.proc.returncode


@pytest.fixture(scope="module")
def start_server() -> Iterator[Callable[..., Server]]:
    """Start servers (ready when returned); all of them stop when the module ends."""
    warm_up(Arena)  # compile the numba kernels once, here, not in every server at once
    started: list[Server] = []

    def start(*args: str, port: int | None = None) -> Server:
        server = Server(port or free_port(), "--time-scale", "0", *args)
        started.append(server)
        return server.wait_ready()

    yield start
    for server in started:
        server.stop()


class RawClient:
    """Sends arbitrary bytes to a server's queryable, as a hostile client would."""

    def __init__(self, port: int) -> None:
        self.port = port
        self.session = zenoh.open(client_config("127.0.0.1", port))

    def send(self, payload: bytes, key: str | None = None, timeout: float = 5.0) -> Reply | None:
        for reply in self.session.get(key or rpc_key(self.port), payload=payload, timeout=timeout):
            assert reply.ok is not None
            return decode_reply(reply.ok.payload.to_bytes())
        return None

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def no_launch(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if a face tries to build a remote client (and so launch a server)."""

    def refuse(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("a server was launched")

    monkeypatch.setattr("neuronsmae.client.rm.RM.__init__", refuse)
    monkeypatch.setattr("neuronsmae.client.vec_rm.VecRM.__init__", refuse)


def numeric(info: dict[str, Any]) -> bool:
    """Whether every value of an info is a Python bool or number, or a numeric array: what
    tensor libraries and EPyMARL's summing logger take."""
    for value in info.values():
        if isinstance(value, np.ndarray):
            if value.dtype.kind not in "biuf":
                return False
        elif not isinstance(value, (bool, int, float)):
            return False
    return True
