"""Shared helpers for the benchmark scripts: timing by medians, CPU clocks, argparse types
for their options, tables and JSON output.

Output convention: a script's JSON goes to the git-ignored ``bench/out/<name>.json``
(:func:`write_json`), replaced by its next run (copies worth keeping go to ``docs/data/``).
A script that takes ``--out FILE`` (:func:`add_out`) writes there instead and refuses a
FILE that exists unless ``--force`` is given, checked before the work starts
(:func:`out_problem`); the file is written whole or not at all (:func:`write_out`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import socket
import statistics
import subprocess
import threading
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.launch import ServerCommand, ServerProcess
from neuronsmae.protocol.messages import MAX_ARENAS
from neuronsmae.trainers.outputs import check_file

if TYPE_CHECKING:
    import psutil

OUT = Path(__file__).resolve().parent / "out"
MAX_PORT = 65_535
"""The highest TCP port."""

CpuSnapshot = dict[tuple[int, int], float]
"""On-CPU seconds so far of each live thread, keyed by (process id, thread id)."""


def rate(fn: Callable[[], int], seconds: float, repeats: int) -> dict[str, float]:
    """Run ``fn`` (which returns how many units it did) for ``seconds`` per repeat, ``repeats``
    times (at least one call each); return the median, min and max rate in units per second."""
    rates = []
    for _ in range(repeats):
        start = time.perf_counter()
        done = fn()
        while time.perf_counter() - start < seconds:
            done += fn()
        rates.append(done / (time.perf_counter() - start))
    return {
        "median": statistics.median(rates),
        "min": min(rates),
        "max": max(rates),
        "repeats": repeats,
    }


class Distinct(argparse.Action):
    """An ``nargs`` option whose values are each given once: a repeat would be measured
    (or run) twice and reported as two rows."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        values = list(values or [])
        repeated = [v for i, v in enumerate(values) if v in values[:i]]
        if repeated:
            parser.error(f"{option_string} gives {repeated[0]} twice: give each value once")
        setattr(namespace, self.dest, values)


def _integer(text: str) -> int:
    """``text`` as an integer, or an argparse refusal naming it."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def at_least(minimum: int) -> Callable[[str], int]:
    """An argparse ``type`` for integers of at least ``minimum``; anything else is refused
    with a message naming the bound."""

    def parse(text: str) -> int:
        value = _integer(text)
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum}, got {value}")
        return value

    return parse


def between(minimum: int, maximum: int) -> Callable[[str], int]:
    """An argparse ``type`` for integers in ``[minimum, maximum]``, refusing others by bounds."""

    def parse(text: str) -> int:
        value = _integer(text)
        if not minimum <= value <= maximum:
            raise argparse.ArgumentTypeError(f"must be in [{minimum}, {maximum}], got {value}")
        return value

    return parse


def tcp_port(text: str) -> int:
    """An argparse ``type`` for a TCP port, in ``[1, MAX_PORT]``."""
    return between(1, MAX_PORT)(text)


def arena_count(text: str) -> int:
    """An argparse ``type`` for arenas on one server or vector, in ``[1, MAX_ARENAS]``."""
    return between(1, MAX_ARENAS)(text)


def finite(
    minimum: float, maximum: float = math.inf, *, above: bool = False
) -> Callable[[str], float]:
    """An argparse ``type`` for finite numbers in [minimum, maximum] (``above``: > minimum)."""
    if maximum < math.inf:
        bound = f"in ({minimum:g}, {maximum:g}]" if above else f"in [{minimum:g}, {maximum:g}]"
    else:
        bound = f"above {minimum:g}" if above else f"of at least {minimum:g}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
        low_ok = value > minimum if above else value >= minimum
        if not (math.isfinite(value) and low_ok and value <= maximum):
            raise argparse.ArgumentTypeError(f"must be a finite number {bound}, got {value}")
        return value

    return parse


positive = finite(0.0, above=True)
"""An argparse ``type`` for finite numbers above 0 (seconds, timeouts, CPU shares)."""
non_negative = finite(0.0)
"""An argparse ``type`` for finite numbers of at least 0 (a budget where 0 means none)."""


PORT_BLOCK = range(24000, 28000)
"""Where the benches and tests take loopback ports for the servers they start: below
Linux's default ephemeral range (32768–60999), from which the kernel gives outgoing
connections their ports (a port picked there can be taken by one before the server binds
it), and above Ray's worker ports (10002–19999)."""


def ephemeral_ports() -> range | None:
    """The kernel's ephemeral port range (``net.ipv4.ip_local_port_range``), if readable."""
    try:
        low, high = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return range(int(low), int(high) + 1)
    except (OSError, ValueError):
        return None


def port_is_free(port: int) -> bool:
    """Nothing is bound to ``port`` on loopback right now."""
    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def free_ports(count: int = 1, block: range = PORT_BLOCK) -> int:
    """The first of ``count`` consecutive loopback ports in ``block`` that are free right
    now, from a random start so that concurrent runs rarely meet. Raises ``RuntimeError``
    when the block lies in the kernel's ephemeral range (whose ports an outgoing connection
    may take at any time) or holds no such ports."""
    ephemeral = ephemeral_ports()
    if ephemeral is not None and block.start < ephemeral.stop and ephemeral.start < block.stop:
        raise RuntimeError(
            f"ports {block.start}-{block.stop - 1} overlap the kernel's ephemeral range "
            f"{ephemeral.start}-{ephemeral.stop - 1} (net.ipv4.ip_local_port_range); "
            "narrow that range or reserve the block (net.ipv4.ip_local_reserved_ports)"
        )
    starts = list(block[: len(block) - count + 1])
    offset = int(np.random.default_rng().integers(len(starts)))
    for base in starts[offset:] + starts[:offset]:
        if all(port_is_free(base + i) for i in range(count)):
            return base
    raise RuntimeError(f"no {count} consecutive free ports in {block.start}-{block.stop - 1}")


def free_port() -> int:
    """A loopback port in :data:`PORT_BLOCK` that nothing is bound to right now (where the
    kernel's ephemeral range covers the block, the kernel's pick)."""
    try:
        return free_ports(1)
    except RuntimeError:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]


ARCHIVE_COMMIT = Path(__file__).resolve().parent / "ARCHIVE_COMMIT"
"""Where ``git archive`` writes the archived commit (``export-subst`` in .gitattributes); in a
checkout it holds the unexpanded placeholder."""


def commit() -> str:
    """The benchmarked code's commit: ``$NEURONSMAE_COMMIT`` when set, else the HEAD of the
    checkout this file is in, wherever the command runs from, else the commit a ``git
    archive`` snapshot was made from (:data:`ARCHIVE_COMMIT`); ``unknown`` outside all."""
    if os.environ.get("NEURONSMAE_COMMIT"):
        return os.environ["NEURONSMAE_COMMIT"]
    try:
        here = Path(__file__).resolve().parent
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             check=True, timeout=10, cwd=here)  # fmt: skip
        return out.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        archived = ARCHIVE_COMMIT.read_text().strip()
    except OSError:
        return "unknown"
    return archived if archived and not archived.startswith("$Format") else "unknown"


def machine() -> dict[str, Any]:
    """What the numbers were measured on."""
    return {
        "python": platform.python_version(),
        "machine": platform.machine(),
        "cpus": os.cpu_count(),
        "load1": os.getloadavg()[0],
    }


def table(rows: list[dict[str, Any]], columns: list[str]) -> str:
    """A Markdown table of ``rows`` restricted to ``columns``."""

    def fmt(v: Any) -> str:
        if not isinstance(v, float):
            return str(v)
        return f"{v:.3f}" if abs(v) < 10 else f"{v:,.1f}"  # ratios keep their digits

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c, "")) for c in columns) + " |" for r in rows]
    return "\n".join(lines)


def write_json(name: str, payload: dict[str, Any]) -> Path:
    """Write ``bench/out/<name>.json`` and return its path."""
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / f"{name}.json"
    path.write_text(json.dumps(payload, indent=2))
    return path


def add_out(parser: argparse.ArgumentParser, name: str | None = None) -> None:
    """``--out FILE`` and ``--force`` (module docstring: the output convention); ``name``:
    the default ``bench/out/<name>.json``, else ``--out`` is required."""
    where = "" if name is None else f" (default: bench/out/{name}.json, replaced each run)"
    parser.add_argument(
        "--out",
        type=Path,
        required=name is None,
        metavar="FILE.json",
        help=f"JSON file to write{where}; an existing one only with --force",
    )
    parser.add_argument("--force", action="store_true", help="replace --out if it exists")


def out_problem(path: Path | None, force: bool) -> str | None:
    """Why the JSON file ``path`` (``--out``) must not be written, or None: not a ``.json``
    name, a folder, a file that exists (unless ``force``), or a folder that cannot be
    created or written into. None for ``path`` None (:func:`write_json`'s default)."""
    if path is None:
        return None
    if path.suffix != ".json" or path.is_dir():
        return f"--out must name a .json file, got {str(path)!r}"
    if path.exists() and not force:
        return f"--out {path} exists; choose another file, or pass --force to replace it"
    try:
        check_file(path, "--out")
    except InvalidOptionError as exc:
        return str(exc)
    return None


def write_out(path: Path, payload: dict[str, Any], indent: int = 2) -> Path:
    """Write ``payload`` as JSON to ``path`` whole or not at all (a temporary file beside
    it, renamed over it); return ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(json.dumps(payload, indent=indent))
    partial.replace(path)
    return path


def process_cpu_seconds(procs: Iterable[psutil.Process]) -> float:
    """User + system CPU seconds so far of ``procs``, ended threads included, in clock ticks:
    for windows of seconds; short rounds use :func:`cpu_snapshot`."""
    return sum(p.cpu_times().user + p.cpu_times().system for p in procs)


def cpu_snapshot(procs: Iterable[psutil.Process]) -> CpuSnapshot:
    """On-CPU seconds of every live thread of ``procs``, to nanoseconds where Linux exposes
    them (``/proc/<pid>/task/<tid>/schedstat``, the scheduler's run time); elsewhere psutil's
    user + system times, which move in clock ticks (10 ms: 31 µs per decision over a round
    of 320). The calling thread reads its own clock (``time.thread_time``): the scheduler
    brings a running thread's ``schedstat`` up to date only at its next tick or switch, so
    the thread taking the snapshot, always running as it does, read up to a tick late there
    (it under-counted an in-process round and over-counted a served one by 1-3 %)."""
    out: CpuSnapshot = {}
    own = (os.getpid(), threading.get_native_id())
    for proc in procs:
        try:
            tids = os.listdir(f"/proc/{proc.pid}/task")
        except OSError:
            tids = []
        for tid in tids:
            try:
                with open(f"/proc/{proc.pid}/task/{tid}/schedstat") as f:
                    out[(proc.pid, int(tid))] = int(f.read().split()[0]) / 1e9
            except (OSError, ValueError, IndexError):
                continue  # the thread ended meanwhile
        if not tids:
            for t in proc.threads():
                out[(proc.pid, t.id)] = t.user_time + t.system_time
    if own in out:
        out[own] = time.thread_time()
    return out


def cpu_between(
    before: CpuSnapshot, after: CpuSnapshot, main: bool | None = None, pid: int | None = None
) -> float:
    """CPU seconds the threads used from ``before`` to ``after``: a thread born in between
    counts from zero, one that ended in between not at all. ``main`` True: the processes'
    main threads only; False: all their other threads (Zenoh's, Ray's, numba's); None: all.
    ``pid``: that process's threads only."""
    return sum(
        t - before.get(key, 0.0)
        for key, t in after.items()
        if (main is None or (key[0] == key[1]) == main) and (pid is None or key[0] == pid)
    )


def cpu_by_thread(before: CpuSnapshot, after: CpuSnapshot, pids: list[int]) -> list[list[float]]:
    """``[[main, other], ...]`` CPU seconds per process of ``pids``, from ``before`` to
    ``after``: the split says whether a cost is the arena's or the transport's."""
    return [[cpu_between(before, after, flag, pid) for flag in (True, False)] for pid in pids]


def start_server(port: int, *, arenas: int = 1, seed: int = 1234) -> ServerProcess:
    """An unpaced ``neuronsmae-server`` holding ``arenas`` arenas on ``port``, started as a
    client launches one (it exits with this process), ready when returned."""
    server = ServerProcess(ServerCommand(port, seed, arenas=arenas, time_scale=0.0))
    from neuronsmae.client import answering_pid  # the client only where a server is started

    server.wait_ready(lambda: answering_pid(port))
    return server


def same(a: Any, b: Any) -> bool:
    """Bit-for-bit equality of nested results (dtype, shape, bytes; -0.0 ≠ 0.0)."""
    if isinstance(a, (np.ndarray, np.generic)):
        return (
            type(a) is type(b)
            and a.dtype == b.dtype
            and a.shape == b.shape
            and a.tobytes() == b.tobytes()
        )
    if isinstance(a, (list, tuple)):
        return isinstance(b, (list, tuple)) and len(a) == len(b) and all(map(same, a, b))
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, float):
        return type(b) is float and np.float64(a).tobytes() == np.float64(b).tobytes()
    return type(a) is type(b) and a == b
