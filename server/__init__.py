"""The simulation side: the in-process :class:`Arena` and the Zenoh server that serves it.

The server never imports the client or the trainers; what it shares with the client lives
in :mod:`neuronsmae.protocol`. Names are imported lazily so that light commands (for example
``neuronsmae-server`` failing fast on a port in use) do not pay for PyBullet and numba.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from neuronsmae.server.arena import Arena
    from neuronsmae.server.config import ArenaConfig
    from neuronsmae.server.contexts import CONTEXT_TABLE, context_table, parse_contexts
    from neuronsmae.server.vec import VecArena

_LAZY = {
    "Arena": "neuronsmae.server.arena",
    "ArenaConfig": "neuronsmae.server.config",
    "CONTEXT_TABLE": "neuronsmae.server.contexts",
    "context_table": "neuronsmae.server.contexts",
    "parse_contexts": "neuronsmae.server.contexts",
    "VecArena": "neuronsmae.server.vec",
}

__all__ = [
    "CONTEXT_TABLE",
    "Arena",
    "ArenaConfig",
    "VecArena",
    "context_table",
    "parse_contexts",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'neuronsmae.server' has no attribute {name!r}")
