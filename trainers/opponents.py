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
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.interface import count_option
from neuronsmae.trainers.agent import (
    PolicyInputError,
    action_mask,
    masked_greedy,
    observations,
    one_hot_width,
)

if TYPE_CHECKING:
    from neuronsmae.trainers.learner import AgentSpec
    from neuronsmae.trainers.rollout import Policy


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
