"""Policies acting greedily for a team across a vector of arenas: red's opponents on the
rollout worker, and either team in ``neuronsmae-match``.

:class:`GreedyTeam` is one policy's agents over ``K`` arenas: a recurrent state and last
actions per arena, and one batched forward pass for every arena it acts in at a decision.
:class:`OpponentActors` is the worker's red side in a competitive arena: each arena's
episode has its opponent (a member of the run's pool, :mod:`neuronsmae.trainers.pool`);
at each decision the arenas are grouped by opponent and each opponent acts for all of its
arenas in one forward pass, next to the learner's own batched pass for blue. Arenas whose
red team a bot drives (``bot_team="red"``) get no-op rows, which the arena ignores.

A policy trained as blue plays red as it is: observations are egocentric (self, team-mates,
enemies) in the field's frame, and with the default random spawns red's scenes are
distributed as blue's are.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

from neuronsmae.trainers.agent import masked_greedy

if TYPE_CHECKING:
    from neuronsmae.trainers.rollout import Policy


class GreedyTeam:
    """``policy``'s agents acting greedily (ε = 0, available actions only) for a team of
    ``n_agents`` robots in each of ``num_envs`` arenas."""

    def __init__(self, policy: Policy, num_envs: int, n_agents: int) -> None:
        self.spec = policy.spec
        self.featurize = policy.spec.featurizer()
        self.agent = policy.spec.build().eval()
        self.agent.load_state_dict({k: torch.as_tensor(v) for k, v in policy.weights.items()})
        self.n = n_agents
        self.hidden = self.agent.initial_hidden(num_envs * n_agents).reshape(num_envs, n_agents, -1)
        self.last = torch.full((num_envs, n_agents), -1, dtype=torch.int64)

    def reset(self, arenas: Sequence[int] | np.ndarray) -> None:
        """Forget the recurrent state of ``arenas`` (their new episodes start)."""
        index = torch.as_tensor(np.asarray(arenas, dtype=np.int64))
        self.hidden[index] = 0.0
        self.last[index] = -1

    @torch.no_grad()
    def act(self, obs: np.ndarray, avail: np.ndarray, arenas: Sequence[int] | np.ndarray
            ) -> np.ndarray:  # fmt: skip
        """Greedy actions ``[m, n_agents]`` for ``arenas`` (m of them) from their raw
        observations ``[m, n_agents, D]`` and masks ``[m, n_agents, A]``."""
        index = torch.as_tensor(np.asarray(arenas, dtype=np.int64))
        m = len(index)
        if m == 0:
            return np.zeros((0, self.n), np.int64)
        x = torch.from_numpy(np.ascontiguousarray(self.featurize(obs), dtype=np.float32))
        inputs = self.spec.inputs(x, self.last[index])  # [m, n, input]
        hidden = self.hidden[index].reshape(1, m * self.n, -1)
        q, hidden = self.agent(inputs.reshape(m * self.n, 1, -1), hidden)
        allowed = torch.from_numpy(np.asarray(avail) > 0).reshape(m * self.n, -1)
        chosen = masked_greedy(q[:, 0], allowed).reshape(m, self.n)
        self.hidden[index] = hidden.reshape(m, self.n, -1)
        self.last[index] = chosen
        return chosen.numpy()


class OpponentActors:
    """Red's side of a worker's competitive arenas: which opponent each arena plays, and
    their actions, batched per opponent."""

    def __init__(self, num_envs: int, n_red: int) -> None:
        self.num_envs, self.n_red = num_envs, n_red
        self.teams: dict[str, GreedyTeam] = {}
        self.current: list[str] = [""] * num_envs
        """Each arena's opponent: a pool member's id, or "" (a bot or nobody: no-op rows)."""
        self.version = -1

    def load(self, policies: Mapping[str, Policy], version: int) -> None:
        """Take the pool's policies (member id → policy) unless this version is loaded.
        Members already loaded keep their state (their weights never change)."""
        if version == self.version:
            return
        kept = {k: t for k, t in self.teams.items() if k in policies}
        for key, policy in policies.items():
            if key not in kept:
                kept[key] = GreedyTeam(policy, self.num_envs, self.n_red)
        self.teams, self.version = kept, version

    def begin(self, arena: int, opponent: str) -> None:
        """Arena ``arena`` starts an episode against ``opponent``: a policy member's id, or
        a bot's (``bot:<level>``) or "" for no-op rows."""
        if not opponent or opponent.startswith("bot:"):
            self.current[arena] = ""
            return
        if opponent not in self.teams:
            raise KeyError(f"opponent {opponent!r} was not sent to this worker")
        self.current[arena] = opponent
        self.teams[opponent].reset([arena])

    def act(self, lo: int, hi: int, obs: np.ndarray, avail: np.ndarray) -> np.ndarray:
        """Red's actions ``[hi - lo, n_red]`` for arenas ``lo .. hi - 1``, from their raw
        red observations and masks (``[hi - lo, n_red, ...]``)."""
        rows = np.zeros((hi - lo, self.n_red), np.int64)
        owners: dict[str, list[int]] = {}
        for j in range(lo, hi):
            if self.current[j]:
                owners.setdefault(self.current[j], []).append(j)
        for key, arenas in owners.items():
            local = np.asarray(arenas) - lo
            rows[local] = self.teams[key].act(obs[local], avail[local], arenas)
        return rows
