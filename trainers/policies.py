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

from neuronsmae.trainers.checkpoint import checkpoint_path, load_checkpoint
from neuronsmae.trainers.evaluate import load_policy
from neuronsmae.trainers.opponents import GreedyTeam
from neuronsmae.trainers.task import trained_options


class CheckpointPolicy:
    """A checkpoint's agents as a :class:`~neuronsmae.protocol.policies.TeamPolicy`."""

    def __init__(self, path: str | Path) -> None:
        payload = load_checkpoint(path)
        self.path = str(checkpoint_path(path))
        self.policy = load_policy(path)
        self.options = trained_options(payload["config"])
        self.env_info = self.policy.spec.env_info
        self.team: GreedyTeam | None = None

    def start(self, num_envs: int, n_agents: int) -> None:
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
