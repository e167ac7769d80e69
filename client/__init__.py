"""The client side of NeuronsMAE: :class:`RM`, the remote arena behind the ``ArenaAPI``.

Depends on :mod:`neuronsmae.protocol` only; a server is reached over Zenoh (and, when none
answers on a local port, started as a subprocess), never imported.
"""

from __future__ import annotations

from neuronsmae.client.rm import RM, context_table, ping

__all__ = ["RM", "context_table", "ping"]
