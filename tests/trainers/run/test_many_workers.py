"""More rollout workers than a 2-core machine's Ray would place: the trainer sizes its own.

Every worker asks for half a CPU, so a Ray that only counted this machine's 2 cores would
place 4 of them and leave the rest pending; the trainer tells its local Ray it has enough
CPUs for all (they share the real cores, oversubscribed), and every episode played is
stored. Nine workers are more than twice what the cores would place; the paper's 20-25 are
sized by the same rule (tests/trainers/run/test_config.py checks it without Ray) and run on
a four-node cluster in tests/trainers/run/test_cluster_scale.py. Each worker is a process
that imports torch, so every one more costs a 2-core machine's suite about 4 s. Tiny runs: a
few episodes each.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from neuronsmae.trainers.run.config import make_config
from neuronsmae.trainers.run.placement import local_cpus
from neuronsmae.trainers.run.train import Trainer
from tests.trainers.conftest import TINY_LEARNER

pytestmark = [pytest.mark.ray, pytest.mark.slow]


def test_many_workers_are_all_placed_and_every_episode_is_stored(tmp_path: Path) -> None:
    workers = 9
    cfg = make_config(
        {
            "workers": workers,
            "episodes": workers + 5,
            "max_minutes": 4.0,
            "env": "inprocess",
            "envs_per_worker": 1,
            "out": str(tmp_path),
            **TINY_LEARNER,
        }
    )
    assert local_cpus(cfg) >= workers * 0.5
    trainer = Trainer(cfg)
    assert trainer.sampler.n_live == workers
    result = trainer.run()
    stored = result["counters"]["episodes"]
    assert stored == workers + 5 == len(trainer.stored_seeds) == len(set(trainer.stored_seeds))
    assert result["final"]["eval_episodes"] == 2
