"""Multi-agent Q-learning for NeuronsMAE: IQL, VDN and QMIX with Ray rollout workers.

One Q-learning core (:mod:`.learner`) with a mixer chosen by name (:mod:`.mixers`), recurrent
agents with shared parameters (:mod:`.agent`), whole-episode replay (:mod:`.buffer`), rollout
workers that become Ray actors at the launch point (:mod:`.rollout`, :mod:`.sampler`), the
training loop (:mod:`.train`), checkpoints (:mod:`.checkpoint`), records (:mod:`.records`),
greedy evaluation (:mod:`.evaluate`) and the ``neuronsmae-train`` command (:mod:`.cli`),
configured by :class:`TrainConfig` and its groups (:mod:`.config`). Experiments that stay
off by default live in :mod:`.experimental`.

Heavy modules (Ray, TensorBoard) are not imported here, so ``evaluate_checkpoint`` can be
used by the match command without starting anything.
"""

from __future__ import annotations

from neuronsmae.trainers.config import ConfigError, TrainConfig, make_config
from neuronsmae.trainers.evaluate import GreedyPolicy, evaluate_checkpoint, load_policy

__all__ = [
    "ConfigError",
    "GreedyPolicy",
    "TrainConfig",
    "evaluate_checkpoint",
    "load_policy",
    "make_config",
]
