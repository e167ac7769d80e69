"""Output paths of the command-line tools (``neuronsmae-match``, ``-league``, ``-plot``),
checked before any game is played or any figure drawn, so a long job never ends in an
error about where its results were to go.

Each check tries what the write will do: it creates the missing folders and a scratch file
in the innermost one, then removes what it created, so nothing is left behind and a folder
the process cannot write (``/proc``, a read-only mount, a file in the way) is refused by the
operating system itself, as root too.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from neuronsmae.protocol.errors import InvalidOptionError


def _unwritable(folder: Path) -> str | None:
    """Why files cannot be written into ``folder`` (created if missing), or None."""
    missing: list[Path] = []
    probe = folder
    while not probe.exists() and probe != probe.parent:
        missing.append(probe)
        probe = probe.parent
    if not probe.is_dir():
        return f"{probe} is a file, not a folder"
    step = ""
    try:
        for made in reversed(missing):
            step = f"create the folder {made}"
            made.mkdir()
        step = f"write into {folder}"
        fd, scratch = tempfile.mkstemp(dir=folder, prefix=".write-check-")
        os.close(fd)
        os.unlink(scratch)
    except OSError as exc:
        return f"cannot {step} ({exc.strerror or exc})"
    finally:
        for made in missing:  # innermost first: leave nothing behind
            try:
                made.rmdir()
            except OSError:
                break
    return None


def check_folder(folder: Path, flag: str) -> None:
    """Refuse ``folder`` (given as ``flag``, e.g. ``--out``) unless it is, or can be
    created as, a folder this process can write files into."""
    reason = _unwritable(Path(folder))
    if reason is not None:
        raise InvalidOptionError(f"{flag} {folder}: {reason}")


def check_file(path: Path, flag: str) -> None:
    """Refuse a file to write (given as ``flag``) that is a folder, or whose folder cannot
    be created or written into. An existing file is fine: it is replaced."""
    path = Path(path)
    if path.is_dir():
        raise InvalidOptionError(f"{flag} {path} is a folder; name a file to write")
    reason = _unwritable(path.parent)
    if reason is not None:
        raise InvalidOptionError(f"{flag} {path}: {reason}")
