"""Where numba keeps the compiled kernels: a directory named by a hash of their sources.

numba's on-disk cache (``cache=True``) checks the source of a kernel's own file only. A
kernel that calls kernels or reads constants of other files (the stepper's fused step calls
the chassis, the world, the shots and the controller) would keep running the old code after
one of those files changed. So every cached kernel of the simulation is kept under one
directory whose name is a hash of every source such a kernel can depend on
(:func:`kernel_sources`): all of ``server/sim`` and ``server/task``, and the protocol
modules they import. Editing any of them makes the next process compile afresh into a new
directory; nothing has to be deleted by hand.

The directories live under ``$NUMBA_CACHE_DIR/neuronsmae`` when ``NUMBA_CACHE_DIR`` is set
(a read-only home, a container), else under ``$XDG_CACHE_HOME/neuronsmae/numba``
(``~/.cache/neuronsmae/numba``), else, if that cannot be written, under the temporary
directory. Each is a few MB; old ones are never read again and can be deleted at any time.

:func:`configure` must run before any kernel is defined, because numba picks a kernel's
cache directory when its decorator runs: the ``server.sim`` and ``server.task`` packages
call it on import, and every kernel module lies inside them. It sets numba's cache
directory for the whole process, which numba offers as a single setting.

Compiling leaves LLVM's memory in the process that compiled, for its whole life (a served
8-arena server: 459 MB resident when it loaded its kernels from the cache, 607 MB when it
compiled them). A server therefore compiles in a throwaway interpreter first
(:func:`compile_aside`) and then loads the kernels; many servers starting together on a cold
cache compile once, in turn behind a file lock. numba's cache index is keyed by each source
file's path and modification time, so every checkout (and every edit) compiles once.
"""

from __future__ import annotations

import fcntl
import functools
import getpass
import hashlib
import os
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numba

SIM = Path(__file__).resolve().parent
"""``server/sim``."""
PROTOCOL_MODULES = ("errors.py", "env_info.py", "actions.py")
"""Modules of ``neuronsmae.protocol`` that kernel modules import (constants, errors, action
checks)."""


def kernel_sources() -> list[Path]:
    """Every file the hash covers, in a fixed order: the ``.py`` files of ``server/sim`` and
    ``server/task``, then :data:`PROTOCOL_MODULES`."""
    protocol = SIM.parents[1] / "protocol"
    files = sorted(SIM.glob("*.py")) + sorted((SIM.parent / "task").glob("*.py"))
    return files + [protocol / name for name in PROTOCOL_MODULES if (protocol / name).is_file()]


def source_hash() -> str:
    """16 hex digits of a SHA-256 over the names and contents of :func:`kernel_sources`."""
    digest = hashlib.sha256()
    for path in kernel_sources():
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


def cache_root() -> Path:
    """The directory holding one sub-directory per source hash (see the module docstring)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "neuronsmae"
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "neuronsmae" / "numba"


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=path).close()
    except OSError:
        return False
    return True


@functools.cache
def configure() -> Path:
    """Point numba's cache at this source tree's directory; return it (once per process)."""
    tag = source_hash()
    directory = cache_root() / tag
    if not _writable(directory):
        directory = Path(tempfile.gettempdir()) / f"neuronsmae-numba-{getpass.getuser()}" / tag
        directory.mkdir(parents=True, exist_ok=True)
    numba.config.CACHE_DIR = str(directory)
    return directory


COMPILE_TIMEOUT_S = 900.0
"""Seconds a throwaway compile may take (about 15-60 s on 2 cores, more on a loaded one)."""


def compiled_marker() -> Path:
    """The file that says this checkout's kernels, as they are on disk now, are cached: its
    name holds a hash of the checkout's path and the newest source modification time (what
    numba's index checks)."""
    newest = max(path.stat().st_mtime_ns for path in kernel_sources())
    where = hashlib.sha256(f"{SIM}|{newest}".encode()).hexdigest()[:16]
    return configure() / f"compiled-{where}"


def compile_aside(command: Sequence[str], timeout: float = COMPILE_TIMEOUT_S) -> bool:
    """Run ``command`` (a fresh interpreter that uses every kernel, then exits) unless
    :func:`compiled_marker` exists; one process at a time. Returns whether it ran.

    Raises ``subprocess.CalledProcessError`` or ``subprocess.TimeoutExpired`` when the
    command fails; the caller then simply compiles in its own process.
    """
    marker = compiled_marker()
    if marker.exists():
        return False
    with open(marker.with_suffix(".lock"), "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)  # released when the file closes
        if marker.exists():  # another process compiled while this one waited
            return False
        subprocess.run(
            list(command), check=True, timeout=timeout, stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        marker.touch()
    return True
