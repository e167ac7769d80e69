"""Start and stop a local ``neuronsmae-server`` for a client that found none.

The server is always a fresh interpreter (``sys.executable -m neuronsmae.server``), never a
fork: a process that holds a Zenoh session must not fork, and the client may hold one. The
server watches the client's pid, so it exits even when the client is killed before it can
call ``close``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable

from neuronsmae.protocol.errors import InvalidOptionError, ServerUnavailableError
from neuronsmae.protocol.transport import MAX_BUSY_POLL_US

STARTUP_TIMEOUT = 120.0
"""Seconds a launched server may take to answer (imports, JIT compiles, arena build)."""
STOP_TIMEOUT = 5.0


def is_local(host: str) -> bool:
    """Whether ``host`` names this machine (only then can a client launch a server for it)."""
    if host in ("localhost", "0.0.0.0", "::"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_launch(time_scale: float, busy_poll_us: float) -> None:
    """Refuse settings the server would exit on, before starting it, naming what is valid."""
    if not time_scale >= 0:  # also refuses NaN
        raise InvalidOptionError(f"time_scale must be >= 0 (0 = unlimited), got {time_scale!r}")
    if not 0 <= busy_poll_us <= MAX_BUSY_POLL_US:
        raise InvalidOptionError(
            f"busy_poll_us must be in [0, {MAX_BUSY_POLL_US:g}] microseconds, got {busy_poll_us!r}"
        )


class ServerProcess:
    """A server launched as a subprocess, with its stderr kept in a temporary log file."""

    def __init__(
        self,
        port: int,
        seed: int,
        host: str,
        time_scale: float,
        no_graphics: bool,
        busy_poll_us: float = 0.0,
    ) -> None:
        check_launch(time_scale, busy_poll_us)
        self.port = port
        self._log = tempfile.NamedTemporaryFile(  # noqa: SIM115 (closed in stop)
            prefix=f"neuronsmae-server-{port}-", suffix=".log", delete=False
        )
        cmd = [
            sys.executable, "-m", "neuronsmae.server",
            "--port", str(port), "--seed", str(seed), "--host", host,
            "--time-scale", str(time_scale), "--watch-parent", str(os.getpid()),
            "--busy-poll", str(busy_poll_us),
        ]  # fmt: skip
        if no_graphics:
            cmd.append("--no-graphics")
        # A new session keeps a Ctrl-C meant for the trainer from killing the server before
        # the trainer has closed it.
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=self._log,
            start_new_session=True,
        )

    def log_tail(self, limit: int = 2000) -> str:
        """The end of the server's stderr, for error messages."""
        with open(self._log.name, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - limit))
            return f.read().decode(errors="replace").strip()

    def wait_ready(self, probe: Callable[[], bool], timeout: float = STARTUP_TIMEOUT) -> None:
        """Poll ``probe`` until it answers True; fail early if the server exits."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise ServerUnavailableError(
                    f"the server launched on port {self.port} exited with status "
                    f"{self.proc.returncode}:\n{self.log_tail()}"
                )
            if probe():
                return
            time.sleep(0.05)
        self.stop()
        raise ServerUnavailableError(
            f"the server launched on port {self.port} did not answer within {timeout:g} s"
        )

    def stop(self) -> None:
        """SIGTERM the server, SIGKILL it if it lingers, and delete its log; idempotent."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if not self._log.closed:
            self._log.close()
            with contextlib.suppress(OSError):
                os.unlink(self._log.name)
