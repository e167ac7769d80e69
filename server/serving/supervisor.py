"""The fleet supervisor: N server subprocesses on consecutive ports, pinged and restarted.

Kept apart from the ``neuronsmae-fleet`` command line (:mod:`neuronsmae.server.serving.fleet`) so a
test or another launcher can drive :class:`Fleet` directly: ``start`` brings the servers
up, ``check`` is one supervision pass (restart what died, ping what runs), ``stop`` ends
them all. Servers are fresh interpreters (``python -m neuronsmae.server``), never forks,
because this process holds Zenoh sessions for its pings.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import subprocess
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from types import FrameType
from typing import IO

from neuronsmae.protocol.defaults import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    DEFAULT_SEED,
    RELEASED_TIME_SCALE,
)
from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.launch import ServerCommand, check_launch
from neuronsmae.protocol.messages import MAX_SEED, max_first_seed
from neuronsmae.server.serving.locators import check_endpoint
from neuronsmae.server.serving.probe import Health, Probe
from neuronsmae.server.serving.rpc import PortInUseError, check_listen_host, check_port
from neuronsmae.server.serving.statefile import (
    StateFile,
    StateFileError,
    check_state_dir,
    state_path,
)

log = logging.getLogger("neuronsmae.serve")

STARTUP_TIMEOUT = 180.0
"""Seconds a server may take to answer its first ping (imports, JIT cache, arena build)."""
STOP_TIMEOUT = 10.0
MAX_BACKOFF = 30.0
MIN_INTERVAL = 0.1
"""Shortest time between two supervision passes, in seconds: shorter is a busy loop of pings."""
BAD_ARGUMENTS = 2
"""The server's exit status for a taken port or bad arguments: restarting cannot help."""


@dataclass(frozen=True)
class FleetSpec:
    """What to run: ``count`` servers from ``base_port``, seeds from ``seed``."""

    base_port: int = DEFAULT_PORT
    count: int = 1
    seed: int = DEFAULT_SEED
    host: str = DEFAULT_HOST
    time_scale: float = RELEASED_TIME_SCALE
    lease: float = 60.0
    routers: tuple[str, ...] = ()
    log_level: str = "WARNING"
    arenas: int = 1
    """Arenas per server (``neuronsmae-server --arenas``); server i's arena j gets seed
    ``seed + i * arenas + j``, so the fleet's arenas have distinct consecutive seeds."""

    def __post_init__(self) -> None:
        check_launch(self.time_scale, 0.0, self.arenas, self.seed)
        if self.seed > max_first_seed(self.count * self.arenas):
            raise InvalidOptionError(
                f"seed {self.seed} + {self.count * self.arenas} arenas passes the largest seed, "
                f"{MAX_SEED}"
            )
        if not (math.isfinite(self.lease) and self.lease > 0):
            raise InvalidOptionError(
                f"lease must be a finite number of seconds > 0, got {self.lease}"
            )
        for router in self.routers:
            check_endpoint(router, "router")

    def ports(self) -> list[int]:
        return [self.base_port + i for i in range(self.count)]


@dataclass
class Member:
    """One server of the fleet and what the supervisor knows about it."""

    index: int
    port: int
    seed: int
    proc: subprocess.Popen[bytes] | None = None
    starts: int = 0
    failures: int = 0
    """Deaths in a row without answering a ping in between (drives the backoff)."""
    restart_at: float | None = None
    """When a dead server is due to start again (None: not dead, or not noticed yet)."""
    missed: int = 0
    answered: bool = False
    last: Health | None = field(default=None, repr=False)

    @property
    def pid(self) -> int | None:
        return self.proc.pid if self.proc is not None else None

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


class Fleet:
    """Starts, watches, restarts and stops the servers of one :class:`FleetSpec`."""

    def __init__(
        self,
        spec: FleetSpec,
        log_dir: Path | None = None,
        state_file: Path | None = None,
        ping_timeout: float = 1.0,
        max_missed: int = 0,
    ) -> None:
        if not (isinstance(max_missed, int) and max_missed >= 0):
            raise InvalidOptionError(
                f"max_missed must be an integer >= 0 (0: restart only when a server exits), "
                f"got {max_missed!r}"
            )
        self.spec = spec
        default_logs = Path(tempfile.gettempdir()) / f"neuronsmae-serve-{spec.base_port}"
        self.log_dir = log_dir or default_logs
        self.state_file = state_file or state_path(spec.base_port)
        check_state_dir(self.state_file, explicit=state_file is not None)
        self._state = StateFile(self.state_file)
        self.max_missed = max_missed
        self.members = [
            Member(i, port, spec.seed + i * spec.arenas) for i, port in enumerate(spec.ports())
        ]
        self.probes = [
            Probe(spec.host, m.port, spec.routers[0] if spec.routers else None, ping_timeout)
            for m in self.members
        ]
        self.restarts = 0

    # ---- lifecycle ---------------------------------------------------------------------

    def __enter__(self) -> Fleet:
        """Create the log folder (FleetStartError when it cannot be one)."""
        try:
            self.log_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise FleetStartError(
                f"log_dir {self.log_dir}: cannot be a folder for the servers' logs "
                f"({exc.strerror or exc})"
            ) from exc
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self, timeout: float = STARTUP_TIMEOUT, stop: StopFlag | None = None) -> None:
        """Start server 0, wait for it (it fills the JIT cache), then start the rest.

        Raises :class:`FleetStartError` when a port is taken, the state file is another
        fleet's (or cannot be written) or a server exits while starting; a server that is
        merely slow is left to :meth:`check`. Nothing is started, and the state file is left
        as it was, unless the ports are free and the state file is this fleet's.
        """
        try:
            check_listen_host(self.spec.host)
        except InvalidOptionError as exc:
            raise FleetStartError(str(exc)) from exc
        for member in self.members:  # else another server's pings would pass for ours
            try:
                check_port(self.spec.host, member.port)
            except PortInUseError as exc:
                msg = f"{exc}; stop what uses it or pick another --base-port"
                raise FleetStartError(msg) from exc
        self._claim_state()
        first, rest = self.members[:1], self.members[1:]
        for group in (first, rest):
            if stop is not None and stop.set:
                return
            for member in group:
                self._spawn(member)
            self._wait_ready(group, timeout, stop)

    def _wait_ready(self, group: list[Member], timeout: float, stop: StopFlag | None) -> None:
        deadline = time.monotonic() + timeout
        waiting = list(group)
        while waiting and time.monotonic() < deadline and not (stop is not None and stop.set):
            for member in list(waiting):
                if not member.alive():
                    code = member.proc.returncode if member.proc is not None else None
                    raise FleetStartError(
                        f"server on port {member.port} exited with status {code}:\n"
                        f"{self.log_tail(member)}"
                    )
                if self._ping(member).up:
                    waiting.remove(member)
            time.sleep(0.1 if waiting else 0.0)
        if stop is not None and stop.set:
            return  # stopping: the servers still starting are about to be stopped
        for member in waiting:
            log.warning("server on port %d is not answering yet", member.port)

    def stop(self) -> None:
        """SIGTERM every server, SIGKILL those still there after ``STOP_TIMEOUT``; mark them
        stopped in the state file if this fleet owns it (a fleet that never started leaves
        the file alone)."""
        running = [m for m in self.members if m.alive()]
        for member in running:
            assert member.proc is not None
            member.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_TIMEOUT
        for member in running:
            assert member.proc is not None
            try:
                member.proc.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                log.warning("server on port %d ignored SIGTERM; killing it", member.port)
                member.proc.kill()
                member.proc.wait()
        for probe in self.probes:
            probe.close()
        self._write_state(stopped=True)

    # ---- supervision -------------------------------------------------------------------

    def check(self) -> list[Health]:
        """One pass: restart what died (when its backoff allows), ping what runs."""
        now = time.monotonic()
        out = []
        for member in self.members:
            if not member.alive():
                out.append(self._dead(member, now))
                continue
            health = self._ping(member)
            if not health.up and member.answered:
                member.missed += 1
                if self.max_missed and member.missed >= self.max_missed:
                    log.warning(
                        "server on port %d missed %d pings; restarting it",
                        member.port,
                        member.missed,
                    )
                    self._kill(member)
                    self._spawn(member)
                    self.restarts += 1
            out.append(health)
        return out

    def _dead(self, member: Member, now: float) -> Health:
        """Schedule a dead server's restart (later each time it dies unheard), or do it."""
        code = member.proc.returncode if member.proc is not None else None
        if member.restart_at is None:
            member.failures += 1
            delay = min(MAX_BACKOFF, 0.5 * 2 ** (member.failures - 1))
            member.restart_at = now + delay
            log.warning(
                "server on port %d (pid %s) exited with status %s; restarting in %.1f s\n%s",
                member.port,
                member.pid,
                code,
                delay,
                self.log_tail(member, 600),
            )
        if now >= member.restart_at:
            self._spawn(member)
            self.restarts += 1
        return Health(member.port, False, error=f"exited with status {code}; restarting")

    def _ping(self, member: Member) -> Health:
        health = self.probes[member.index].ping()
        member.last = health
        if health.up:
            member.answered, member.missed, member.failures = True, 0, 0
        return health

    def run(self, stop: StopFlag, interval: float = 2.0) -> None:
        """Supervise until ``stop`` is set, checking every ``interval`` seconds (finite,
        at least :data:`MIN_INTERVAL`)."""
        check_interval(interval)
        while not stop.set:
            self.check()
            stop.sleep(interval)

    # ---- processes ---------------------------------------------------------------------

    def command(self, member: Member) -> ServerCommand:
        """The server's command (``watch_parent``: no orphans if we are killed)."""
        spec = self.spec
        return ServerCommand(
            port=member.port,
            seed=member.seed,
            host=spec.host,
            arenas=spec.arenas,
            time_scale=spec.time_scale,
            lease=spec.lease,
            routers=spec.routers,
            log_level=spec.log_level,
        )

    def log_file(self, member: Member) -> Path:
        return self.log_dir / f"server-{member.port}.log"

    def log_tail(self, member: Member, limit: int = 2000) -> str:
        """The end of the server's log, for messages about why it stopped."""
        try:
            with self.log_file(member).open("rb") as f:
                f.seek(0, os.SEEK_END)
                f.seek(max(0, f.tell() - limit))
                return f.read().decode(errors="replace").strip()
        except OSError:
            return ""

    def _spawn(self, member: Member) -> None:
        self.log_dir.mkdir(parents=True, exist_ok=True)
        with self.log_file(member).open("ab") as logf:
            _stamp(logf, f"start {member.starts + 1} of the server on port {member.port}")
            member.proc = self.command(member).spawn(logf)
        member.starts += 1
        member.restart_at, member.missed, member.answered = None, 0, False
        self.probes[member.index].close()
        log.info("started server on port %d (pid %d)", member.port, member.proc.pid)
        self._write_state()

    def _kill(self, member: Member) -> None:
        if member.proc is not None and member.proc.poll() is None:
            member.proc.kill()
            member.proc.wait()

    def _claim_state(self) -> None:
        """Make the state file this fleet's before any server starts (FleetStartError when
        it belongs to another fleet, is no fleet's state, or cannot be written)."""
        try:
            self._state.claim(self._state_record())
        except StateFileError as exc:
            raise FleetStartError(str(exc)) from exc
        except OSError as exc:
            raise FleetStartError(
                f"fleet state file {self.state_file} cannot be written "
                f"({exc.strerror or exc}); choose a writable folder with NEURONSMAE_STATE_DIR"
            ) from exc

    def _write_state(self, stopped: bool = False) -> None:
        """Record the pids (None once ``stopped``), if this fleet owns the state file."""
        try:
            self._state.write(self._state_record(stopped))
        except OSError as exc:  # supervision goes on; only ``status`` loses the pids
            log.warning("cannot write the fleet state file %s: %s", self.state_file, exc)

    def _state_record(self, stopped: bool = False) -> dict[str, object]:
        return {
            "fleet_pid": None if stopped else os.getpid(),
            "spec": asdict(self.spec),
            "servers": [
                {
                    "port": m.port,
                    "seed": m.seed,
                    "pid": None if stopped else m.pid,
                    "starts": m.starts,
                    "log": str(self.log_file(m)),
                }
                for m in self.members
            ],
        }


def check_interval(interval: object) -> None:
    """Refuse a supervision interval that is not a finite number of seconds >=
    :data:`MIN_INTERVAL`, naming it."""
    number = isinstance(interval, (int, float)) and not isinstance(interval, bool)
    if not (number and MIN_INTERVAL <= interval < math.inf):  # type: ignore[operator]
        raise InvalidOptionError(
            f"interval must be a finite number of seconds >= {MIN_INTERVAL}, got {interval!r}"
        )


class FleetStartError(NeuronsMAEError):
    """The fleet cannot start: a port is taken, the host or the log folder is unusable, or a
    server exited during startup (bad arguments)."""

    code = "fleet_start"


class StopFlag:
    """SIGINT/SIGTERM set a flag that the loops poll, so no signal lands mid-restart."""

    def __init__(self) -> None:
        self.set = False

    def install(self) -> None:
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, self._handler)

    def _handler(self, signum: int, frame: FrameType | None) -> None:
        log.info("received %s; stopping the servers", signal.Signals(signum).name)
        self.set = True

    def sleep(self, seconds: float) -> None:
        """Sleep up to ``seconds``, waking within 0.1 s of a stop request."""
        end = time.monotonic() + seconds
        while not self.set and (left := end - time.monotonic()) > 0:
            time.sleep(min(0.1, left))


def _stamp(logf: IO[bytes], text: str) -> None:
    logf.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} {text} ---\n".encode())
    logf.flush()
