"""After a half turn, candidate points are listed in the environment's order again, and each
taken action still names the point it drove to."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import Batch, EpisodeReplayBuffer
from neuronsmae.trainers.core.learner import AgentSpec
from neuronsmae.trainers.core.symmetry import UnknownSymmetryError, task_group, transform
from neuronsmae.trainers.play.rollout import RolloutWorker

K = 4


@pytest.fixture(scope="module")
def batch() -> tuple[Batch, EnvInfo]:
    """Four real episodes of the abstract 2 v 2 against easy, raw observations, ε = 1."""
    worker = RolloutWorker(0, "inprocess", 11, 10000)
    info = EnvInfo.from_dict(worker.env_info())
    spec = AgentSpec(info.obs_shape + info.n_actions + 2, info.n_actions, 16, True, True,
                     "raw", "flat")  # fmt: skip
    policy = Policy(spec, {k: v.numpy() for k, v in spec.build().state_dict().items()})
    buffer = EpisodeReplayBuffer(8, 2, info.obs_shape, info.state_shape, info.n_actions, 50)
    try:
        for seed in range(4):
            buffer.add(worker.run_episode(policy, 0, 1.0, seed, {"level": "easy"}))
    finally:
        worker.close()
    return buffer.sample(4, np.random.default_rng(0)), info


def _points(obs: torch.Tensor, info: EnvInfo) -> torch.Tensor:
    """``[..., E, k, 2]`` candidate points of each enemy, and ``[..., E, 2]`` the enemy."""
    cols = torch.tensor([[list(info.obs.point(j, q)) for q in range(K)] for j in range(2)])
    return obs[..., cols]


def _enemies(obs: torch.Tensor, info: EnvInfo) -> torch.Tensor:
    return obs[..., torch.tensor([list(info.obs.pose(info.obs.enemy(j))[:2]) for j in range(2)])]


def _in_environment_order(obs: torch.Tensor, info: EnvInfo) -> torch.Tensor:
    """Per (step, agent, enemy): distinct points by angle from +x, then copies of the last."""
    points = _points(obs, info)
    side = points - _enemies(obs, info).unsqueeze(-2)
    angle = torch.remainder(torch.atan2(side[..., 1], side[..., 0]), 2 * math.pi)
    same = (points[..., 1:, :] == points[..., :-1, :]).all(-1)
    rising = angle[..., 1:] > angle[..., :-1]
    copies_stop = same[..., :-1] & ~same[..., 1:]  # a copy, then a new point again
    return (rising | same).all(-1) & ~copies_stop.any(-1)


def test_turned_points_are_listed_as_the_environment_lists_them(
    batch: tuple[Batch, EnvInfo],
) -> None:
    episodes, info = batch
    real = torch.cat([episodes.filled, episodes.filled[:, -1:]], 1) > 0  # steps and the last obs
    assert bool(_in_environment_order(episodes.obs, info)[real].all())  # the premise
    field = next(g for g in task_group(("field",), "raw", info) if g.name == "field")
    unordered = transform(episodes, replace(field, points=None))  # the half turn alone
    assert not bool(_in_environment_order(unordered.obs, info)[real].all())
    turned = transform(episodes, field)
    assert bool(_in_environment_order(turned.obs, info)[real].all())
    torch.testing.assert_close(  # the same points, only listed again
        _points(turned.obs, info).sort(-2).values[real], _points(unordered.obs, info)
        .sort(-2).values[real],
    )  # fmt: skip


def test_each_taken_action_still_names_its_point(batch: tuple[Batch, EnvInfo]) -> None:
    episodes, info = batch
    turned = transform(episodes, task_group(("field",), "raw", info)[1])
    steps = episodes.filled > 0
    before = _points(episodes.obs[:, :-1], info)
    after = _points(turned.obs[:, :-1], info)
    j, c = episodes.actions // K, episodes.actions % K
    j2, c2 = turned.actions // K, turned.actions % K
    alive = episodes.alive[:, :-1] > 0
    moved = 0
    for b, t, a in zip(*torch.nonzero(steps.unsqueeze(-1) & alive, as_tuple=True), strict=True):
        assert j2[b, t, a] == j[b, t, a]
        torch.testing.assert_close(after[b, t, a, j2[b, t, a], c2[b, t, a]],
                                   -before[b, t, a, j[b, t, a], c[b, t, a]])  # fmt: skip
        moved += int(c2[b, t, a] != c[b, t, a])
    assert moved > 0  # the relabelling did something on these episodes
    taken = turned.avail[:, :-1].gather(-1, turned.actions.unsqueeze(-1)).squeeze(-1)
    assert bool(taken[steps].all())
    torch.testing.assert_close(turned.last_actions[:, 1:], turned.actions)


def test_abstract_actions_without_observed_points_cannot_be_turned(
    batch: tuple[Batch, EnvInfo],
) -> None:
    played = batch[1]  # the same task without the 2 · k · 2 point columns
    info = replace(played, candidate_obs=False, obs_shape=played.obs_shape - 2 * K * 2)
    with pytest.raises(UnknownSymmetryError, match="the candidate points in the observation"):
        task_group(("field",), "raw", info)
    assert len(task_group(("enemies", "allies"), "raw", info)) == 4
