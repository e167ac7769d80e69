"""Helpers shared by the trainer tests: synthetic episodes for buffer and learner checks, and
the loopback switch the local multi-node Ray clusters need."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import ray
from ray._private import ray_constants

from neuronsmae.trainers.core.buffer import Episode

N_AGENTS, OBS, STATE, ACTIONS, LIMIT = 2, 5, 4, 3, 6
TINY_LEARNER = {
    "progress": False,
    "agent_hidden": 16,
    "mixer_embed": 8,
    "hypernet_hidden": 8,
    "batch_size": 4,
    "learning_starts": 4,
    "eval_every": 0,
    "final_eval_episodes": 2,
}
"""A learner and evaluation small enough for runs of many workers on 2 cores."""


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


@pytest.fixture(scope="module")
def loopback_ray() -> Iterator[None]:
    """Keep every Ray address on 127.0.0.1.

    Ray rewrites a loopback address to the machine's outward IP (``resolve_ip_for_localhost``)
    unless "clusters" are off; the switch is read once at import, so it is patched here
    and set in the environment for the processes the cluster starts. The cluster is also
    kept out of ``/tmp/ray/ray_current_cluster``: a plain ``ray.init()`` elsewhere on the
    machine would join it while it runs (and its shutdown would delete another's entry).
    """
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR, "0")
        mp.setattr(ray_constants, "ENABLE_RAY_CLUSTER", False)
        mp.setattr(ray._private.utils, "write_ray_address", lambda *a, **k: None)
        mp.setattr(ray._common.utils, "reset_ray_address", lambda *a, **k: None)
        yield
