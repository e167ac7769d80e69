"""Multi-agent Q-learning for NeuronsMAE: IQL, VDN and QMIX with Ray rollout workers.

One Q-learning core (:mod:`.learner`) with a mixer chosen by name (:mod:`.mixers`), recurrent
agents with shared parameters (:mod:`.agent`), whole-episode replay (:mod:`.buffer`), rollout
workers that become Ray actors at the launch point (:mod:`.rollout`, :mod:`.sampler`), the
training loop (:mod:`.train`), checkpoints (:mod:`.checkpoint`), records (:mod:`.records`),
greedy evaluation (:mod:`.evaluate`) and the ``neuronsmae-train`` command (:mod:`.cli`),
configured by :class:`TrainConfig` and its groups (:mod:`.config`). Competitive play: the
task's options (:mod:`.task`), the opponent pool and self-play (:mod:`.pool`,
:mod:`.competition`, :mod:`.opponents`), ``neuronsmae-match`` (:mod:`.match`) and
``neuronsmae-league`` (:mod:`.league`). Experiments that stay off by default live in
:mod:`.experimental`.

Names are imported lazily: ``neuronsmae-match`` between bots loads neither torch nor Ray.
"""

from __future__ import annotations

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from neuronsmae.trainers.config import ConfigError, TrainConfig, make_config
    from neuronsmae.trainers.evaluate import GreedyPolicy, evaluate_checkpoint, load_policy

_LAZY = {
    "ConfigError": "neuronsmae.trainers.config",
    "TrainConfig": "neuronsmae.trainers.config",
    "make_config": "neuronsmae.trainers.config",
    "GreedyPolicy": "neuronsmae.trainers.evaluate",
    "evaluate_checkpoint": "neuronsmae.trainers.evaluate",
    "load_policy": "neuronsmae.trainers.evaluate",
}

__all__ = [
    "ConfigError",
    "GreedyPolicy",
    "TrainConfig",
    "evaluate_checkpoint",
    "load_policy",
    "make_config",
]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'neuronsmae.trainers' has no attribute {name!r}")
