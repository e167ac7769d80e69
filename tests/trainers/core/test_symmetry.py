"""The task's symmetries: they commute with the features, keep episodes valid, and undo."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.server.sim.field import FIELD_X, FIELD_Y, OBSTACLES
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import EpisodeReplayBuffer
from neuronsmae.trainers.core.features import feature_dim, get_features
from neuronsmae.trainers.core.learner import AgentSpec
from neuronsmae.trainers.core.symmetry import (
    GENERATORS,
    UnknownSymmetryError,
    augment,
    parse_generators,
    task_group,
    transform,
)
from neuronsmae.trainers.play.rollout import RolloutWorker
from neuronsmae.trainers.run.config import ConfigError, make_config

ALL = ("enemies", "field", "allies")
INFO = EnvInfo.from_dict(
    {"n_actions": 8, "n_agents": 2, "state_shape": 21, "obs_shape": 37, "episode_limit": 50,
     "action_space": "abstract", "agents": ["blue_0", "blue_1"], "n_enemies": 2,
     "decision_steps": 20, "mode": "cooperative", "team_size": 2, "k": 4,
     "candidate_obs": True, "vector_obs": True, "lidar_beams": 0}
)  # fmt: skip
"""The abstract 2 v 2 the workers of :func:`raw_buffer` play."""


@pytest.fixture(scope="module")
def raw_buffer() -> EpisodeReplayBuffer:
    """Three real episodes of the abstract 2 v 2 against easy, raw observations, ε = 1."""
    worker = RolloutWorker(0, "inprocess", 7, 10000)
    assert EnvInfo.from_dict(worker.env_info()) == INFO
    spec = AgentSpec(37 + 8 + 2, 8, 16, True, True, "raw", "flat")
    agent = spec.build()
    policy = Policy(spec, {k: v.numpy() for k, v in agent.state_dict().items()})
    buffer = EpisodeReplayBuffer(8, 2, 37, 21, 8, 50)
    try:
        for seed in range(3):
            buffer.add(worker.run_episode(policy, 0, 1.0, seed, {"level": "easy"}))
    finally:
        worker.close()
    return buffer


def _featurized(batch_obs: torch.Tensor, features: str) -> torch.Tensor:
    return torch.from_numpy(get_features(features, INFO)(batch_obs.numpy()))


@pytest.mark.parametrize("features", ["relative"])
def test_every_symmetry_commutes_with_the_features(
    raw_buffer: EpisodeReplayBuffer, features: str
) -> None:
    """Transforming raw observations then featurizing equals featurizing then transforming:
    the column bookkeeping of the derived features is right for every group element."""
    batch = raw_buffer.sample(3, np.random.default_rng(0))
    raw_group = task_group(ALL, "raw", INFO)
    feat_group = task_group(ALL, features, INFO)
    assert feat_group[1].obs.index.shape == (feature_dim(features, INFO),)
    assert [g.name for g in raw_group] == [g.name for g in feat_group]
    steps = batch.filled.sum(1).long()
    for g_raw, g_feat in zip(raw_group, feat_group, strict=True):
        then_feat = _featurized(transform(batch, g_raw).obs, features)
        feat_then = transform(
            type(batch)(**{**batch.__dict__, "obs": _featurized(batch.obs, features)}), g_feat
        ).obs
        for b in range(batch.obs.shape[0]):  # padding rows are zeros, not observations
            real = slice(0, int(steps[b]) + 1)
            torch.testing.assert_close(
                feat_then[b, real], then_feat[b, real], atol=2e-5, rtol=0, msg=g_raw.name
            )


def test_group_size_names_and_involutions(raw_buffer: EpisodeReplayBuffer) -> None:
    batch = raw_buffer.sample(3, np.random.default_rng(1))
    group = task_group(ALL, "raw", INFO)
    assert len(group) == 8 and group[0].name == "identity"
    assert {g.name for g in group} >= {"enemies", "field", "allies", "enemies+field+allies"}
    for g in group:  # every generator is an involution and they commute
        twice = transform(transform(batch, g), g)
        for f in ("obs", "state", "avail", "alive", "actions", "last_actions"):
            torch.testing.assert_close(getattr(twice, f), getattr(batch, f), atol=1e-6, rtol=0)


def test_transformed_episodes_stay_consistent(raw_buffer: EpisodeReplayBuffer) -> None:
    """Taken actions stay available, last actions follow the actions, and the generators
    move exactly the columns they name."""
    batch = raw_buffer.sample(3, np.random.default_rng(2))
    by_name = {g.name: g for g in task_group(ALL, "raw", INFO)}
    real = batch.filled > 0
    for g in by_name.values():
        out = transform(batch, g)
        taken = out.avail[:, :-1].gather(-1, out.actions.unsqueeze(-1)).squeeze(-1)
        assert bool(taken[real].all()), g.name
        torch.testing.assert_close(out.last_actions[:, 1:], out.actions)
        assert bool((out.last_actions[:, 0] == -1).all())

    swap = transform(batch, by_name["enemies"])
    torch.testing.assert_close(swap.obs[..., 6:9], batch.obs[..., 9:12])
    torch.testing.assert_close(swap.obs[..., 20:28], batch.obs[..., 12:20])
    torch.testing.assert_close(swap.state[..., 10:15], batch.state[..., 15:20])
    torch.testing.assert_close(swap.actions, (batch.actions + 4) % 8)

    turn = transform(batch, by_name["field"])
    torch.testing.assert_close(turn.obs[..., 0:2], -batch.obs[..., 0:2])
    yaw = turn.obs[..., 2] * np.pi - batch.obs[..., 2] * np.pi
    torch.testing.assert_close(torch.cos(yaw), -torch.ones_like(yaw), atol=1e-5, rtol=0)
    torch.testing.assert_close(turn.obs[..., 28:], batch.obs[..., 28:])  # time, HP, bullets

    allies = transform(batch, by_name["allies"])
    torch.testing.assert_close(allies.obs, batch.obs.flip(2))
    torch.testing.assert_close(allies.state[..., 0:5], batch.state[..., 5:10])


def test_the_field_is_centrally_symmetric() -> None:
    """The premise of ``field``: every obstacle has a partner half a turn away (within 2 cm)."""
    centres = np.array([(o.cx, o.cy) for o in OBSTACLES])
    turned = np.array([FIELD_X, FIELD_Y]) - centres
    gaps = np.linalg.norm(turned[:, None] - centres[None], axis=-1).min(axis=1)
    assert gaps.max() < 0.02, gaps


def test_augment_draws_per_episode_and_none_is_free(raw_buffer: EpisodeReplayBuffer) -> None:
    batch = raw_buffer.sample(3, np.random.default_rng(3))
    rng = np.random.default_rng(4)
    same = augment(batch, task_group((), "raw", INFO), rng)
    assert same is batch
    assert rng.integers(1 << 30) == np.random.default_rng(4).integers(1 << 30)  # no draw

    group = task_group(("enemies",), "raw", INFO)
    big = raw_buffer.sample(64, np.random.default_rng(5))
    out = augment(big, group, np.random.default_rng(6))
    swapped = (out.actions != big.actions).flatten(1).any(1)
    assert 0 < int(swapped.sum()) < 64  # some episodes swapped, some kept
    every = transform(big, group[1])
    for f in ("obs", "state", "avail", "actions", "last_actions"):
        torch.testing.assert_close(getattr(out, f)[swapped], getattr(every, f)[swapped])
        torch.testing.assert_close(getattr(out, f)[~swapped], getattr(big, f)[~swapped])
    torch.testing.assert_close(out.rewards, big.rewards)


def test_errors_name_the_valid_choices() -> None:
    assert parse_generators("none") == () and parse_generators("enemies, field") == (
        "enemies",
        "field",
    )
    with pytest.raises(UnknownSymmetryError, match="enemies, field, allies"):
        parse_generators("mirror")
    with pytest.raises(UnknownSymmetryError, match="distinct"):
        parse_generators("field,field")
    with pytest.raises(ConfigError, match="augment"):
        make_config({"augment": "enemy"})
    lidar = EnvInfo.from_dict({**INFO.to_dict(), "lidar_beams": 61, "obs_shape": 98})
    with pytest.raises(UnknownSymmetryError, match="needs poses in the observation and no LiDAR"):
        task_group(("field",), "raw", lidar)
    three = {"n_enemies": 3, "n_actions": 12, "obs_shape": 3 * 5 + 24 + 1 + 10, "state_shape": 26}
    wide = EnvInfo.from_dict({**INFO.to_dict(), **three})
    with pytest.raises(UnknownSymmetryError, match="needs two enemies"):
        task_group(("enemies", "field"), "raw", wide)
    assert len(task_group(("field",), "relative", wide)) == 2  # the half turn fits any team
    assert GENERATORS == ALL
    assert len(task_group((), "raw", lidar)) == 1  # no generators: any task
