"""The client side of NeuronsMAE: :class:`RM`, the remote arena behind the ``ArenaAPI``, and
:class:`VecRM`, many remote arenas behind the ``VecArenaAPI``.

Depends on :mod:`neuronsmae.protocol` only; a server is reached over Zenoh (and, when none
answers on a local port, started as a subprocess), never imported.
"""

from __future__ import annotations

from neuronsmae.client.rm import RM, context_table, ping
from neuronsmae.client.vec_rm import VecRM

__all__ = ["RM", "VecRM", "context_table", "ping"]

# Ecosystem faces (Gymnasium, PettingZoo) over any ArenaAPI; registers NeuronsMAE/Coop-v0.
from neuronsmae.client.gym_env import CoopEnv, register_envs
from neuronsmae.client.pz_env import ArenaParallelEnv, parallel_env

__all__ += ["ArenaParallelEnv", "CoopEnv", "parallel_env"]
register_envs()
