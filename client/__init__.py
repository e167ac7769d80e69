"""The client side of NeuronsMAE: :class:`RM`, the remote arena behind the ``ArenaAPI``,
:class:`VecRM`, many remote arenas behind the ``VecArenaAPI``, and the faces the usual RL
libraries expect (docs/ecosystem.md).

Depends on :mod:`neuronsmae.protocol` only; a server is reached over Zenoh (and, when none
answers on a local port, started as a subprocess), never imported — unless a face, or
:func:`make_arena` / :func:`make_vec_arena`, is told to build its arena in this process
(``env="inprocess"``, or ``"neuronsmae.server:Arena"``), which imports it by name.
"""

from __future__ import annotations

from neuronsmae.client.rm import RM, answering_pid, context_table, ping
from neuronsmae.client.source import make_arena, make_vec_arena
from neuronsmae.client.vec_rm import VecRM

__all__ = ["RM", "VecRM", "answering_pid", "context_table", "make_arena", "make_vec_arena", "ping"]

# Faces (Gymnasium, PettingZoo, SMAC) over any ArenaAPI; registers the Gymnasium ids
# NeuronsMAE/Coop-v0 and NeuronsMAE/Agents-v0.
from neuronsmae.client.agents_env import AgentsEnv
from neuronsmae.client.gym_env import CoopEnv, register_envs
from neuronsmae.client.pz_env import ArenaParallelEnv, parallel_env
from neuronsmae.client.smac import SMACEnv
from neuronsmae.client.vec_env import CoopVectorEnv

__all__ += ["AgentsEnv", "ArenaParallelEnv", "CoopEnv", "CoopVectorEnv", "SMACEnv", "parallel_env"]
register_envs()
