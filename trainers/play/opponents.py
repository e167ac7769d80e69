"""Red's side of a rollout worker's competitive arenas: each arena's episode has its
opponent (a member of the run's pool, :mod:`neuronsmae.trainers.play.pool`); at each decision
the arenas are grouped by opponent and each opponent acts for all of its arenas in one
forward pass (a :class:`~neuronsmae.trainers.core.acting.GreedyTeam`), next to the learner's
own batched pass for blue. Arenas whose red team a bot drives (``bot_team="red"``) get
no-op rows, which the arena ignores.

A policy trained as blue plays red as it is: observations are egocentric (self, team-mates,
enemies) in the field's frame, and with the default random spawns red's scenes are
distributed as blue's are.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from neuronsmae.trainers.core.acting import GreedyTeam, Policy


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
