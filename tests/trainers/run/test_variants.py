"""Every task variant trains: a short run of each through Ray, sized from the arena.

Abstract and discrete actions; full and partial observability; LiDAR with and without the
referee vector; 1 v 1, 3 v 3 and unequal teams; dense and sparse reward; every bot
(``random`` and the released levels included) through a pool of bots; per-episode
contexts; self-play on another task than the default. Each run plays four episodes with
an update, a final greedy evaluation and a checkpoint whose networks fit the arena the
workers opened. One local Ray (2 CPUs) serves the module.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import pytest
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.protocol.levels import LEVEL_ARGS
from neuronsmae.server import Arena
from neuronsmae.trainers.play.task import blue_view
from neuronsmae.trainers.run.config import make_config
from neuronsmae.trainers.run.train import train

pytestmark = [pytest.mark.ray, pytest.mark.slow, pytest.mark.usefixtures("local_ray")]

TINY = {
    "workers": 1, "env": "inprocess", "episodes": 4, "envs_per_worker": 2, "agent_hidden": 16,
    "hypernet_hidden": 8, "mixer_embed": 8, "batch_size": 2, "learning_starts": 2,
    "eval_every": 0, "keep_best": False, "final_eval_episodes": 2, "max_minutes": 0,
    "progress": False, "worker_cpus": 0.5, "snapshot_every": 2,
}  # fmt: skip

VARIANTS: dict[str, dict[str, Any]] = {
    "discrete": {"arena.action_space": "discrete"},
    "partial": {"arena.observability": "partial"},
    "lidar": {"arena.lidar": True},
    "lidar_only": {"arena.lidar": True, "arena.vector_obs": False},
    "1v1": {"arena.n_blue": 1, "arena.n_red": 1},
    "3v3_contexts": {"arena.n_blue": 3, "arena.n_red": 3,
                     "contexts": "coef=0.5..1.5;opponent.VK1=0.3,0.375"},
    "3v2": {"arena.n_blue": 3, "arena.n_red": 2, "alg": "qmix"},
    "1v2": {"arena.n_blue": 1, "arena.n_red": 2, "alg": "iql"},
    "sparse": {"arena.reward": "sparse"},
    "every_bot": {"opponent": ",".join(LEVEL_ARGS), "level": "random", "episodes": 8},
    "selfplay_1v1_discrete_partial": {
        "opponent": "self,hard", "arena.n_blue": 1, "arena.n_red": 1,
        "arena.action_space": "discrete", "arena.observability": "partial",
    },
}  # fmt: skip


@pytest.mark.parametrize("name", list(VARIANTS))
def test_every_variant_trains(name: str, tmp_path: Path) -> None:
    cfg = make_config(TINY, VARIANTS[name], {"out": str(tmp_path)})
    result = train(cfg)
    assert result["counters"]["episodes"] == cfg.episodes and result["counters"]["updates"] > 0
    assert result["final"]["eval_episodes"] == 2
    mode = "competitive" if "self" in cfg.opponent else "cooperative"
    probe = Arena(seed=0, **cfg.arena.arena_options(mode))
    try:
        want = blue_view(EnvInfo.from_dict(probe.get_env_info()))
    finally:
        probe.close()
    saved = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    assert saved["agent_spec"]["env_info"] == want.to_dict()
    assert saved["env"]["n_agents"] == cfg.arena.n_blue
    assert saved["env"]["n_actions"] == want.n_actions
    with (tmp_path / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == cfg.episodes
    if name == "every_bot":  # each episode's bot is its pool draw's
        assert all(json.loads(r["contexts"])["level"] == _level(r["opponent"]) for r in rows)
    if name == "3v3_contexts":
        assert len({json.loads(r["contexts"])["coef"] for r in rows}) == len(rows)


def _level(member: str) -> int | str:
    value = member.removeprefix("bot:")
    return int(value) if value in ("0", "1") else value
