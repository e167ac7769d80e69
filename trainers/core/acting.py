"""Acting with a trained agent network: the policy a worker receives, and a team of its
agents acting greedily across a vector of arenas.

:class:`Policy` is what travels from the learner to whoever acts: the network's
architecture (:class:`~neuronsmae.trainers.core.learner.AgentSpec`) and its weights.
:class:`GreedyTeam` is one policy's agents over ``K`` arenas: a recurrent state and last
actions per arena, and one batched forward pass for every arena it acts in at a decision
(red's opponents on a rollout worker, either team in ``neuronsmae-match``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.interface import count_option
from neuronsmae.trainers.core.agent import (
    PolicyInputError,
    action_mask,
    masked_greedy,
    observations,
    one_hot_width,
)
from neuronsmae.trainers.core.learner import AgentSpec


@dataclass(frozen=True)
class Policy:
    """What a worker needs to act: the agent architecture and its weights.

    The architecture travels with the weights so a worker can be started before the
    learner knows the environment's sizes (it learns them from the first worker).
    """

    spec: AgentSpec
    """Agent network architecture and input options."""
    weights: dict[str, np.ndarray]
    """The agent's ``state_dict`` as NumPy arrays."""


def acting_shape(spec: AgentSpec, n_agents: int) -> tuple[int, int]:
    """The team size and raw observation width ``spec``'s network acts on: those of the
    layout it carries, else ``n_agents`` and what its input width leaves for the observation
    (raw features then). :class:`InvalidOptionError` if the layout's team is not
    ``n_agents`` robots."""
    if spec.env_info is not None:
        team = int(spec.env_info["n_agents"])
        if n_agents != team:
            raise InvalidOptionError(
                f"n_agents={n_agents}: this policy's agents were trained as a team of {team} "
                f"and drive teams of {team} only"
            )
        return team, int(spec.env_info["obs_shape"])
    return n_agents, spec.input_dim - one_hot_width(spec, n_agents)


class GreedyTeam:
    """``policy``'s agents acting greedily (ε = 0, available actions only) for a team of
    ``n_agents`` robots in each of ``num_envs`` arenas.

    ``num_envs`` and ``n_agents`` are checked (:class:`InvalidOptionError`), and so is what
    :meth:`reset` and :meth:`act` are given (:class:`PolicyInputError`): shapes, masks,
    and arena indices in range and each named once, so a bad call changes no arena's state.
    """

    def __init__(self, policy: Policy, num_envs: int, n_agents: int) -> None:
        num_envs = count_option("num_envs", num_envs, 1)
        n_agents = count_option("n_agents", n_agents, 1)
        self.spec = policy.spec
        self.n, self.obs_dim = acting_shape(policy.spec, n_agents)
        self.featurize = policy.spec.featurizer()
        self.agent = policy.spec.build().eval()
        self.agent.load_state_dict({k: torch.as_tensor(v) for k, v in policy.weights.items()})
        self.num_envs = num_envs
        self.hidden = self.agent.initial_hidden(num_envs * n_agents).reshape(num_envs, n_agents, -1)
        self.last = torch.full((num_envs, n_agents), -1, dtype=torch.int64)

    def _index(self, arenas: Any, once: bool) -> np.ndarray:
        """``arenas`` as int64 indices, each in ``[0, num_envs)`` (and named ``once``)."""
        if isinstance(arenas, list) and all(type(i) is int for i in arenas):
            picked = arenas  # the callers' usual form, checked in Python (a fraction of a µs)
        else:
            index = np.asarray(arenas)
            if index.ndim != 1 or (index.size and index.dtype.kind not in "iu"):
                raise PolicyInputError(
                    f"arenas must be a sequence of arena indices in [0, {self.num_envs - 1}], "
                    f"got {type(arenas).__name__} {arenas!r:.60}"
                )
            picked = index.tolist()
        if picked and (min(picked) < 0 or max(picked) >= self.num_envs):
            raise PolicyInputError(
                f"arenas must be in [0, {self.num_envs - 1}] (the num_envs={self.num_envs} "
                f"given to start), got {picked!r:.80}"
            )
        if once and len(set(picked)) != len(picked):
            raise PolicyInputError(f"arenas names an arena twice: {picked!r:.80}")
        return np.array(picked, dtype=np.int64)

    def reset(self, arenas: Sequence[int] | np.ndarray) -> None:
        """Forget the recurrent state of ``arenas`` (their new episodes start)."""
        index = torch.from_numpy(self._index(arenas, once=False))
        self.hidden[index] = 0.0
        self.last[index] = -1

    @torch.no_grad()
    def act(self, obs: np.ndarray, avail: np.ndarray, arenas: Sequence[int] | np.ndarray
            ) -> np.ndarray:  # fmt: skip
        """Greedy actions ``[m, n_agents]`` for ``arenas`` (m of them) from their raw
        observations ``[m, n_agents, D]`` and masks ``[m, n_agents, A]``."""
        picked = self._index(arenas, once=True)
        m, n = picked.size, self.n
        raw = observations(obs, (m, n, self.obs_dim), ("len(arenas)", "n_agents", "obs_dim"))
        mask = action_mask(avail, (m, n, self.spec.n_actions),
                           ("len(arenas)", "n_agents", "n_actions"), picked)  # fmt: skip
        if m == 0:
            return np.zeros((0, n), np.int64)
        index = torch.from_numpy(picked)
        x = torch.from_numpy(np.ascontiguousarray(self.featurize(raw), dtype=np.float32))
        inputs = self.spec.inputs(x, self.last[index])  # [m, n, input]
        hidden = self.hidden[index].reshape(1, m * n, -1)
        q, hidden = self.agent(inputs.reshape(m * n, 1, -1), hidden)
        chosen = masked_greedy(q[:, 0], self.spec.mask(mask).reshape(m * n, -1)).reshape(m, n)
        self.hidden[index] = hidden.reshape(m, n, -1)
        self.last[index] = chosen
        return chosen.numpy()
