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
"""

from __future__ import annotations

import functools
import getpass
import hashlib
import os
import tempfile
from pathlib import Path

import numba

SIM = Path(__file__).resolve().parent
"""``server/sim``."""
PROTOCOL_MODULES = ("errors.py", "env_info.py")
"""Modules of ``neuronsmae.protocol`` that kernel modules import (constants, errors)."""


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
