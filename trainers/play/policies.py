"""The trainers' checkpoints as team policies for ``neuronsmae-match`` and the league.

:func:`load` is the trainers' ``neuronsmae.policies`` entry point ("qlearner"): given a
checkpoint file (``checkpoint.pt``, ``best.pt``, a snapshot) or a run directory it returns
a :class:`CheckpointPolicy`, the checkpoint's agents acting greedily (ε = 0, available
actions only) for a team across a vector of arenas; given anything else, None.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.interface import count_option
from neuronsmae.trainers.core.acting import GreedyTeam, Policy
from neuronsmae.trainers.core.checkpoint import acting_parts, checkpoint_path, load_checkpoint
from neuronsmae.trainers.play.evaluate import checkpoint_options


class CheckpointPolicy:
    """A checkpoint's agents as a :class:`~neuronsmae.protocol.policies.TeamPolicy`.

    The checkpoint is checked as it loads (:class:`CheckpointError` naming the file), the
    team :meth:`start` is given against the checkpoint's (``InvalidOptionError``), and
    :meth:`reset` and :meth:`act` check their arguments (shapes ``[m, n_agents, ...]``,
    arena indices in range and each named once, masks of 0/1 that leave every agent an
    action: :class:`~neuronsmae.trainers.core.agent.PolicyInputError`)."""

    def __init__(self, path: str | Path) -> None:
        payload = load_checkpoint(path)
        self.path = str(checkpoint_path(path))
        spec, weights, self.n_agents = acting_parts(payload, path)
        self.policy = Policy(spec, weights)
        self.options = checkpoint_options(payload, path)
        self.env_info = spec.env_info
        self.team: GreedyTeam | None = None

    def start(self, num_envs: int, n_agents: int) -> None:
        n_agents = count_option("n_agents", n_agents, 1)
        if n_agents != self.n_agents:
            raise InvalidOptionError(
                f"n_agents={n_agents}: {self.path} holds agents of a team of "
                f"{self.n_agents} and drives teams of {self.n_agents} robots only"
            )
        self.team = GreedyTeam(self.policy, num_envs, n_agents)

    def reset(self, arenas: Sequence[int]) -> None:
        self._team().reset(arenas)

    def act(self, obs: np.ndarray, avail: np.ndarray, arenas: Sequence[int]) -> np.ndarray:
        return self._team().act(obs, avail, arenas)

    def _team(self) -> GreedyTeam:
        if self.team is None:
            raise RuntimeError("call start(num_envs, n_agents) before reset() or act()")
        return self.team


def load(text: str) -> CheckpointPolicy | None:
    """The entry point: a checkpoint file or run directory, else None."""
    if not checkpoint_path(text).is_file():
        return None
    return CheckpointPolicy(text)
