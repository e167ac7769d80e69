"""The fleet's state file: which pids serve which ports, for ``neuronsmae-fleet status``.

One file per base port, ``$NEURONSMAE_STATE_DIR/neuronsmae-serve-<base>.json`` (the system's
temp folder when the variable is unset or empty; the name keeps the command's former name, so
``status`` still finds a fleet started before the rename). The variable must name an existing
folder: it is not created, so a mistyped path is refused before any server starts instead of
scattering state where ``status`` will never look.

A fleet writes the file only once it has *claimed* it (:meth:`StateFile.claim`), which it
does before starting any server and only when the file is absent or is the state of a fleet
that no longer runs. So a second fleet that fails to start, or that would share the file
with a running one, leaves the running fleet's state alone, and a file that is no fleet's
state (a ``--state-file`` pointing at something else) is never overwritten.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError

STATE_ENV = "NEURONSMAE_STATE_DIR"


class StateFileError(NeuronsMAEError, ValueError):
    """A state file that cannot be read, is no fleet's state, or belongs to a running fleet."""

    code = "state_file"


def state_path(base_port: int) -> Path:
    """Where the fleet on ``base_port`` records its pids (``$NEURONSMAE_STATE_DIR`` or tmp)."""
    root = os.environ.get(STATE_ENV) or tempfile.gettempdir()
    return Path(root) / f"neuronsmae-serve-{base_port}.json"


def check_state_dir(path: Path, explicit: bool) -> None:
    """Refuse a state file whose folder does not exist, naming where the path came from:
    ``$NEURONSMAE_STATE_DIR`` unless the file was given ``explicit``-ly."""
    folder = path.parent
    if folder.is_dir():
        return
    what = "is not a folder" if folder.exists() else "does not exist"
    if explicit:
        raise InvalidOptionError(f"state_file {path}: its folder {folder} {what}")
    raise InvalidOptionError(
        f"{STATE_ENV}={os.environ.get(STATE_ENV)}: {folder} {what}; it must name an "
        f"existing folder for the fleet's state file (create it, or unset {STATE_ENV} to "
        f"use {tempfile.gettempdir()})"
    )


def pid_alive(pid: object) -> bool:
    """Whether ``pid`` is a process that exists (``kill(pid, 0)``; 0 and negative pids, which
    name process groups, and non-integers are not)."""
    if not isinstance(pid, int) or isinstance(pid, bool) or pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OverflowError:
        return False
    return True


def load(path: Path) -> dict[str, Any] | None:
    """The fleet state in ``path``, None when there is no such file.

    Raises :class:`StateFileError` naming the file when it cannot be read or is not a
    fleet's state: a JSON object whose ``servers`` is a list of objects, each with an
    integer ``port`` in 1..65535.
    """
    try:
        text = path.read_text()
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise StateFileError(f"fleet state file {path} cannot be read: {exc}") from exc
    try:
        state = json.loads(text)
    except ValueError as exc:
        raise StateFileError(f"fleet state file {path} is not JSON: {exc}") from exc
    problem = _shape_problem(state)
    if problem:
        raise StateFileError(f"fleet state file {path} is not a fleet's state: {problem}")
    return state


def _shape_problem(state: object) -> str | None:
    if not isinstance(state, dict):
        return f"a JSON {type(state).__name__}, not an object"
    servers = state.get("servers", [])
    if not isinstance(servers, list):
        return f"servers is {servers!r}, not a list"
    for i, server in enumerate(servers):
        port = server.get("port") if isinstance(server, dict) else None
        if not isinstance(port, int) or isinstance(port, bool) or not 0 < port < 65536:
            return f"servers[{i}] is {server!r}, not an object with a port in 1..65535"
    return None


class StateFile:
    """One fleet's hold on its state file: nothing is written before :meth:`claim`."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.owned = False

    def claim(self, state: dict[str, Any]) -> None:
        """Take the file and write ``state`` to it, unless it is another running fleet's or
        no fleet's state (:class:`StateFileError`); OSError when it cannot be written."""
        if self.owned:
            self.write(state)
            return
        own = f"give this fleet a state file of its own ({STATE_ENV}=<another folder>)"
        try:
            current = load(self.path)
        except StateFileError as exc:
            raise StateFileError(f"{exc}; not overwriting it: remove it or {own}") from exc
        if current is not None and pid_alive(current.get("fleet_pid")):
            raise StateFileError(
                f"fleet state file {self.path} belongs to a running fleet "
                f"(pid {current['fleet_pid']}); stop that fleet or {own}"
            )
        self._replace(state)
        self.owned = True

    def write(self, state: dict[str, Any]) -> None:
        """Replace the file with ``state`` if this fleet owns it; otherwise do nothing."""
        if self.owned:
            self._replace(state)

    def _replace(self, state: dict[str, Any]) -> None:
        tmp = self.path.with_name(f"{self.path.name}.{os.getpid()}.{id(self):x}.tmp")
        try:
            tmp.write_text(json.dumps(state, indent=1))
            tmp.replace(self.path)  # atomic: ``status`` never reads half a file
        finally:
            tmp.unlink(missing_ok=True)
