"""Acting from checkpoints: the saved weights are what loads, and acting is greedy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from neuronsmae.server.arena import Arena
from neuronsmae.trainers.checkpoint import Counters, save_checkpoint
from neuronsmae.trainers.config import TrainConfig
from neuronsmae.trainers.evaluate import GreedyPolicy, act_greedily, load_policy
from neuronsmae.trainers.learner import EnvSpec, QLearner, agent_spec

ENV = EnvSpec(n_agents=2, n_actions=8, obs_dim=37, state_dim=21, episode_limit=50)


def _checkpoint(path: Path, seed: int) -> QLearner:
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


def test_checkpoint_hands_out_the_agents_weights(tmp_path: Path) -> None:
    learner = _checkpoint(tmp_path / "checkpoint.pt", 0)
    policy = load_policy(tmp_path)  # the run directory finds checkpoint.pt
    assert policy.spec == learner.spec
    for k, v in learner.acting_weights().items():
        assert np.array_equal(policy.weights[k], v)


def test_greedy_policy_takes_the_best_available_action_and_values_the_team(
    tmp_path: Path,
) -> None:
    _checkpoint(tmp_path / "a.pt", 10)
    policy, twin = GreedyPolicy(tmp_path / "a.pt"), GreedyPolicy(tmp_path / "a.pt")
    rng = np.random.default_rng(0)
    for _ in range(4):
        obs = list(rng.uniform(-1, 1, (2, 37)).astype(np.float32))
        avail = list((rng.random((2, 8)) < 0.6).astype(np.int8))
        for mask in avail:
            mask[rng.integers(8)] = 1
        q = twin.q_values(obs).masked_fill(torch.as_tensor(np.asarray(avail)) == 0, -np.inf)
        chosen, value = act_greedily(policy, obs, avail)
        assert chosen == q.argmax(dim=-1).tolist()
        assert value == pytest.approx(float(q.max(dim=-1).values.sum()), rel=1e-6)
        twin.chose(torch.as_tensor(chosen))
        assert policy.last is not None and policy.last.tolist() == chosen


def test_greedy_policy_plays_a_whole_episode(tmp_path: Path) -> None:
    _checkpoint(tmp_path / "a.pt", 1)
    policy = GreedyPolicy(tmp_path / "a.pt")
    arena = Arena(seed=3, action_space="abstract")
    try:
        obs, done, taken = arena.reset(seed=5), False, 0
        policy.reset()
        while not done:
            avail = arena.get_avail_actions()
            actions = policy.act(obs, avail)
            assert all(mask[a] for mask, a in zip(avail, actions, strict=True))
            obs, _, done, _ = arena.step(actions)
            taken += 1
    finally:
        arena.close()
    assert taken > 1


@pytest.mark.slow
def test_a_checkpoint_is_evaluated_on_the_task_it_trained_on(tmp_path: Path) -> None:
    from neuronsmae.trainers.evaluate import evaluate_checkpoint
    from tests.trainers.checkpoints import make_checkpoint

    path = make_checkpoint(tmp_path / "3v3.pt", 1, n_blue=3, n_red=3, reward="sparse")
    result = evaluate_checkpoint(path, "random", episodes=2, seed=3, envs=2)
    assert result["eval_episodes"] == 2 and result["level"] == "random"
    assert result["mean_return"] in (-1.0, 0.0, 1.0, -0.5, 0.5)  # sparse: ±1 or 0 per episode


@pytest.mark.parametrize("level", ["2", 2, "medium", 1.5, True])
def test_an_unknown_level_is_refused_before_anything_loads(level: object, tmp_path: Path) -> None:
    from neuronsmae.protocol.errors import InvalidContextError
    from neuronsmae.trainers.evaluate import evaluate_checkpoint

    with pytest.raises(InvalidContextError, match="'easy', 'middle' and 'hard'") as err:
        evaluate_checkpoint(tmp_path / "missing.pt", level, episodes=1, seed=0)  # type: ignore[arg-type]
    assert repr(level) in str(err.value)
