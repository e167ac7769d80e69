"""Checkpoints made without training: a fresh agent for a task, saved in checkpoint format.

Matches and leagues only need policies that act; untrained weights (each seed its own)
give distinct, deterministic players in a fraction of a second.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.server import Arena
from neuronsmae.trainers.core.checkpoint import Counters, save_checkpoint
from neuronsmae.trainers.core.learner import EnvSpec, agent_spec
from neuronsmae.trainers.play.task import blue_view
from neuronsmae.trainers.run.config import make_config
from neuronsmae.trainers.run.config_groups import resolve_learner


def make_checkpoint(path: Path, seed: int, **arena: Any) -> Path:
    """A checkpoint of a fresh 16-unit agent (weights from ``seed``) for the task of the
    ``arena.<name>`` keys ``arena``; returns ``path``."""
    cfg = make_config({f"arena.{k}": v for k, v in arena.items()}, {"agent_hidden": 16})
    probe = Arena(seed=0, **cfg.arena.arena_options("cooperative"))
    try:
        info = blue_view(EnvInfo.from_dict(probe.get_env_info()))
    finally:
        probe.close()
    lc = resolve_learner(cfg.learner, info, cfg.arena.observability, cfg.arena.spawn)
    env = EnvSpec.of(info, lc.features)
    spec = agent_spec(env, 16, True, True, lc.features, lc.head, info)
    torch.manual_seed(seed)
    agent = spec.build()
    save_checkpoint(
        path,
        config=cfg.to_dict(),
        env=env,
        spec=spec,
        learner_state={"agent": agent.state_dict()},
        counters=Counters(),
        np_rng=np.random.default_rng(seed),
    )
    return path
