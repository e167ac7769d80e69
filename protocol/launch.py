"""Starting a ``neuronsmae-server`` process: its command line, built in one place.

Clients (``RM`` and ``VecRM`` launching a server they found missing, the trainers' Ray
actors) and the server side's fleet supervisor all start servers through
:class:`ServerCommand`. A server is always a fresh interpreter
(``sys.executable -m neuronsmae.server``), never a fork, because a process that holds a
Zenoh session must not fork; it runs in a session of its own (a Ctrl-C meant for its parent
reaches it only through the parent's orderly stop) and, with ``watch_parent``, exits when
its parent dies.
"""

from __future__ import annotations

import functools
import ipaddress
import math
import numbers
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from neuronsmae.protocol.defaults import DEFAULT_HOST, DEFAULT_SEED, UNPACED
from neuronsmae.protocol.errors import InvalidOptionError, ServerUnavailableError
from neuronsmae.protocol.messages import MAX_ARENAS, max_first_seed
from neuronsmae.protocol.transport import MAX_BUSY_POLL_US, check_tls

STARTUP_TIMEOUT = 120.0
"""Seconds a launched server may take to answer (imports, JIT compiles, arena builds)."""
STOP_TIMEOUT = 5.0
"""Seconds a server gets to leave after SIGTERM before it is killed."""
PORT_IN_USE_STATUS = 2
"""A server's exit status when its port is taken (or its arguments are wrong)."""


def is_local(host: str) -> bool:
    """Whether ``host`` names this machine (only then can a client launch a server for it)."""
    if host in ("localhost", "0.0.0.0", "::"):
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def free_port(host: str = DEFAULT_HOST) -> int:
    """A TCP port nothing listens on right now (the kernel's pick; it may be taken again
    before a server binds it, which the server reports by exiting with status 2)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.bind((host.strip("[]"), 0))
        return int(s.getsockname()[1])


def check_launch(
    time_scale: float, busy_poll_us: float, arenas: int = 1, seed: int | None = None
) -> None:
    """Refuse settings the server would exit on, before starting it, naming what is valid
    (``seed``: the first arena's; the others take the next ones)."""
    if not (math.isfinite(time_scale) and time_scale >= 0):
        raise InvalidOptionError(
            f"time_scale must be a finite number >= 0 (0 = unlimited), got {time_scale!r}"
        )
    if not 0 <= busy_poll_us <= MAX_BUSY_POLL_US:
        raise InvalidOptionError(
            f"busy_poll_us must be in [0, {MAX_BUSY_POLL_US:g}] microseconds, got {busy_poll_us!r}"
        )
    if isinstance(arenas, bool) or not isinstance(arenas, int) or not 1 <= arenas <= MAX_ARENAS:
        raise InvalidOptionError(f"arenas must be an integer in [1, {MAX_ARENAS}], got {arenas!r}")
    if seed is not None:
        integer = isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_))
        top = max_first_seed(arenas)
        if not integer or not 0 <= int(seed) <= top:
            raise InvalidOptionError(
                f"seed must be an integer in [0, {top}] (arena i is seeded seed + i), got {seed!r}"
            )


@dataclass(frozen=True)
class ServerCommand:
    """What a server is started with: each field is one ``neuronsmae-server`` flag."""

    port: int
    """TCP port to listen on (``--port``); its key is ``neuronsmae/<port>/rpc``."""
    seed: int = DEFAULT_SEED
    """Seed of arena 0 until a client configures its own; arena i gets ``seed + i``."""
    host: str = DEFAULT_HOST
    """Address to listen on (``--host``)."""
    arenas: int = 1
    """Arenas this server holds, stepped together by one vector request (``--arenas``)."""
    time_scale: float = UNPACED
    """Cap on simulated/real time per request (``--time-scale``; 0 = unlimited)."""
    busy_poll_us: float = 0.0
    """Microseconds to poll for the next request before sleeping (``--busy-poll``)."""
    lease: float | None = None
    """Seconds of owner silence before another client may take over (None: the default)."""
    routers: tuple[str, ...] = ()
    """Zenoh routers the server also connects to (``--router``, repeated)."""
    log_level: str | None = None
    """``--log-level`` (None: the server's default, WARNING)."""
    watch_parent: bool = True
    """Pass this process's pid (``--watch-parent``): the server exits when it dies."""

    def __post_init__(self) -> None:
        check_launch(self.time_scale, self.busy_poll_us, self.arenas)

    def argv(self) -> list[str]:
        """The full command line, ``sys.executable -m neuronsmae.server ...``."""
        cmd = [
            sys.executable, "-m", "neuronsmae.server",
            "--port", str(self.port), "--seed", str(self.seed), "--host", self.host,
            "--arenas", str(self.arenas), "--time-scale", str(self.time_scale),
            "--busy-poll", str(self.busy_poll_us), "--no-graphics",
        ]  # fmt: skip
        if self.lease is not None:
            cmd += ["--lease", str(self.lease)]
        for router in self.routers:
            cmd += ["--router", router]
        if self.log_level is not None:
            cmd += ["--log-level", self.log_level]
        if self.watch_parent:
            cmd += ["--watch-parent", str(os.getpid())]
        return cmd

    def spawn(self, log: IO[Any] | int) -> subprocess.Popen[bytes]:
        """Start the server with stdout and stderr going to ``log``."""
        return subprocess.Popen(
            self.argv(),
            stdin=subprocess.DEVNULL,
            stdout=log,
            stderr=log,
            start_new_session=True,
        )


class ServerProcess:
    """A server launched for one client, its output kept in an unnamed temporary file.

    The file is unlinked as it is created (``tempfile.TemporaryFile``): it has no name in
    the temporary directory, so nothing is left behind however either process ends. (A
    named log, deleted by :meth:`stop`, stayed behind whenever the client was killed with
    SIGKILL or left through ``os._exit``, as Ray does to its workers: one file per server.)
    The kernel frees it when its last descriptor closes: this process's, kept until
    :meth:`stop` for :meth:`log_tail` (the message of a server that fails to start), and the
    server's stdout and stderr, kept until it exits, which it does by itself when this
    process dies (``watch_parent``). While the server runs its output is readable at
    ``/proc/<server pid>/fd/2``.
    """

    def __init__(self, command: ServerCommand) -> None:
        check_tls()  # the server would read the same NEURONSMAE_ZENOH_TLS file and just exit
        self.command = command
        self.port = command.port
        self._log = tempfile.TemporaryFile(  # noqa: SIM115 (closed in stop)
            prefix=f"neuronsmae-server-{command.port}-", suffix=".log", buffering=0
        )
        try:
            self.proc = command.spawn(self._log)
        except BaseException:
            self._log.close()
            raise

    def log_tail(self, limit: int = 2000) -> str:
        """The end of the server's output, for error messages ("" once stopped).

        Read with ``pread``, at an explicit offset: the server's stdout shares this
        descriptor's file offset, so a seek here would make it write over its own log."""
        if self._log.closed:
            return ""
        fd = self._log.fileno()
        size = os.fstat(fd).st_size
        start = max(0, size - limit)
        return os.pread(fd, size - start, start).decode(errors="replace").strip()

    def exited(self) -> int | None:
        """The exit status if the server has exited, else None."""
        return self.proc.poll()

    def wait_ready(self, probe: Callable[[], int | None], timeout: float = STARTUP_TIMEOUT) -> None:
        """Poll ``probe`` until this server answers; fail early if it exits.

        ``probe`` returns the ``pid`` of the ping reply on this server's port, or None
        while nothing answers. Only this process's own pid counts: another server that
        bound the port between the pick and the launch answers too, and this one then
        exits with :data:`PORT_IN_USE_STATUS`.
        """
        deadline = time.monotonic() + timeout
        other = None
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise ServerUnavailableError(
                    f"the server launched on port {self.port} exited with status "
                    f"{self.proc.returncode}:\n{self.log_tail()}"
                )
            pid = probe()
            if pid == self.proc.pid:
                return
            other = pid if pid is not None else other
            time.sleep(0.05)
        self.stop()
        who = "" if other is None else f" (another server, pid {other}, answers on it)"
        raise ServerUnavailableError(
            f"the server launched on port {self.port} did not answer within {timeout:g} s{who}"
        )

    def stop(self) -> None:
        """SIGTERM the server, SIGKILL it if it lingers, and close its log (which frees it:
        it has no name); idempotent."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(STOP_TIMEOUT)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()


def launch_private(
    make: Callable[[int], ServerCommand],
    ready: Callable[[int], int | None],
    host: str = DEFAULT_HOST,
    attempts: int = 5,
    timeout: float = STARTUP_TIMEOUT,
) -> ServerProcess:
    """Launch a server on a free port of ``host`` (``make(port)`` builds its command) and
    wait until it answers (``ready(port)`` is the pid answering a ping on ``port``, None
    while nothing does); a port taken between the pick and the bind is retried."""
    for _ in range(attempts):
        port = free_port(host)
        server = ServerProcess(make(port))
        try:
            server.wait_ready(functools.partial(ready, port), timeout)
            return server
        except ServerUnavailableError:
            if server.exited() != PORT_IN_USE_STATUS:
                server.stop()
                raise
            server.stop()
    raise ServerUnavailableError(f"no free port on {host} after {attempts} attempts")


def check_timeout(timeout: Any, name: str = "timeout") -> None:
    """Refuse a timeout that is not a finite number of seconds > 0, naming it."""
    number = isinstance(timeout, numbers.Real) and not isinstance(timeout, bool)
    if not (number and math.isfinite(timeout) and timeout > 0):
        raise InvalidOptionError(f"{name} must be a finite number of seconds > 0, got {timeout!r}")


def ports_of(port: int | Sequence[int] | None) -> list[int] | None:
    """``None`` (private servers), one port, or several distinct ones, as a list (None
    stays None)."""
    if port is None:
        return None
    ports = [port] if isinstance(port, int) else list(port)
    bad = [p for p in ports if isinstance(p, bool) or not isinstance(p, int) or not 0 < p < 65536]
    if not ports or bad:
        raise InvalidOptionError(
            f"port must be an integer in 1..65535 or a list of them, got {port!r}"
        )
    twice = sorted({p for p in ports if ports.count(p) > 1})
    if twice:  # one server serves one client: the second connection would be refused busy
        raise InvalidOptionError(f"port lists each server once; listed twice: {twice}")
    return ports
