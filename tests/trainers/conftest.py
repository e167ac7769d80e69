"""Helpers shared by the trainer tests: synthetic episodes for buffer and learner checks."""

from __future__ import annotations

import numpy as np

from neuronsmae.trainers.buffer import Episode

N_AGENTS, OBS, STATE, ACTIONS, LIMIT = 2, 5, 4, 3, 6


def make_episode(
    length: int, rng: np.random.Generator, *, dead_from: int | None = None, terminated: bool = True
) -> Episode:
    """An episode of ``length`` decisions; agent 1 is destroyed from step ``dead_from``."""
    alive = np.ones((length + 1, N_AGENTS), dtype=bool)
    avail = np.ones((length + 1, N_AGENTS, ACTIONS), np.int8)
    actions = rng.integers(0, ACTIONS, (length, N_AGENTS))
    if dead_from is not None:
        alive[dead_from:, 1] = False
        avail[dead_from:, 1] = [1, 0, 0]
        actions[dead_from:, 1] = 0
    return Episode(
        obs=rng.standard_normal((length + 1, N_AGENTS, OBS)).astype(np.float32),
        state=rng.standard_normal((length + 1, STATE)).astype(np.float32),
        avail=avail,
        alive=alive,
        actions=actions.astype(np.int64),
        rewards=rng.standard_normal(length).astype(np.float32),
        terminated=terminated,
    )
