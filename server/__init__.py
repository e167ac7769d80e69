"""The simulation side: the in-process :class:`Arena` and the Zenoh server that serves it.

The server never imports the client or the trainers; what it shares with the client lives
in :mod:`neuronsmae.protocol`.
"""

from __future__ import annotations

from neuronsmae.server.arena import Arena
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.contexts import CONTEXT_TABLE, context_table, parse_contexts

__all__ = ["CONTEXT_TABLE", "Arena", "ArenaConfig", "context_table", "parse_contexts"]
