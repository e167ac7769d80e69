"""Acting from checkpoints: the evaluated weights are what loads, and ensembles average Q."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuronsmae.server.arena import Arena
from neuronsmae.trainers.checkpoint import Counters, save_checkpoint
from neuronsmae.trainers.config import TrainConfig
from neuronsmae.trainers.evaluate import (
    EnsemblePolicy,
    GreedyPolicy,
    act_greedily,
    load_policy,
)
from neuronsmae.trainers.learner import EnvSpec, QLearner, agent_spec

ENV = EnvSpec(n_agents=2, n_actions=8, obs_dim=37, state_dim=21, episode_limit=50)


def _checkpoint(path: Path, seed: int, eval_ema: float = 0.0) -> QLearner:
    torch.manual_seed(seed)
    learner = QLearner(
        ENV,
        agent_spec(ENV, 16, True, True),
        "vdn",
        lr=1e-3,
        gamma=0.99,
        grad_clip=10.0,
        target_update_interval=10,
        double_q=True,
        mixer_embed=8,
        hypernet_hidden=8,
        eval_ema=eval_ema,
    )
    save_checkpoint(
        path,
        config=TrainConfig().to_dict(),
        env=ENV,
        spec=learner.spec,
        learner_state=learner.state_dict(),
        counters=Counters(),
        np_rng=np.random.default_rng(seed),
    )
    return learner


def test_checkpoint_hands_out_the_weight_average_when_the_run_kept_one(tmp_path: Path) -> None:
    learner = _checkpoint(tmp_path / "a.pt", 0, eval_ema=0.1)
    with torch.no_grad():  # make the average differ from the latest weights
        for p in learner.average_agent.parameters():  # type: ignore[union-attr]
            p.add_(1.0)
    state = learner.state_dict()
    save_checkpoint(
        tmp_path / "a.pt",
        config=TrainConfig().to_dict(),
        env=ENV,
        spec=learner.spec,
        learner_state=state,
        counters=Counters(),
        np_rng=np.random.default_rng(0),
    )
    loaded = load_policy(tmp_path / "a.pt").weights
    for k, v in learner.policy_weights().items():
        assert np.array_equal(loaded[k], v)
    assert not np.array_equal(loaded["fc1.weight"], learner.acting_weights()["fc1.weight"])


def test_ensemble_of_one_plays_exactly_like_its_checkpoint(tmp_path: Path) -> None:
    _checkpoint(tmp_path / "a.pt", 1)
    alone, ensemble = GreedyPolicy(tmp_path / "a.pt"), EnsemblePolicy([tmp_path / "a.pt"])
    arena = Arena(seed=3, action_space="abstract")
    try:
        obs, done, taken = arena.reset(seed=5), False, 0
        alone.reset()
        ensemble.reset()
        while not done:
            avail = arena.get_avail_actions()
            actions = alone.act(obs, avail)
            assert ensemble.act(obs, avail) == actions
            obs, _, done, _ = arena.step(actions)
            taken += 1
    finally:
        arena.close()
    assert taken > 1


def test_ensemble_acts_greedily_on_the_mean_q_values_them_and_tells_every_member(
    tmp_path: Path,
) -> None:
    paths = [tmp_path / "a.pt", tmp_path / "b.pt"]
    for seed, path in enumerate(paths):
        _checkpoint(path, 10 + seed)
    ensemble, twins = EnsemblePolicy(paths), [GreedyPolicy(p) for p in paths]
    rng = np.random.default_rng(0)
    for _ in range(4):
        obs = list(rng.uniform(-1, 1, (2, 37)).astype(np.float32))
        avail = list((rng.random((2, 8)) < 0.6).astype(np.int8))
        for mask in avail:
            mask[rng.integers(8)] = 1
        mean_q = torch.stack([t.q_values(obs) for t in twins]).mean(dim=0)
        mean_q = mean_q.masked_fill(torch.as_tensor(np.asarray(avail)) == 0, -np.inf)
        chosen, value = act_greedily(ensemble, obs, avail)
        assert chosen == mean_q.argmax(dim=-1).tolist()
        assert value == pytest.approx(float(mean_q.max(dim=-1).values.sum()), rel=1e-6)
        for twin, member in zip(twins, ensemble.members, strict=True):
            twin.chose(torch.as_tensor(chosen))
            assert member.last is not None and member.last.tolist() == chosen


def test_ensemble_refuses_no_checkpoints() -> None:
    with pytest.raises(ValueError, match="at least one"):
        EnsemblePolicy([])
