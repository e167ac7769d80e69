"""Derived input features: the raw observation is kept and the geometry is right."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch

from neuronsmae.protocol import EnvInfo
from neuronsmae.trainers.core.features import (
    Relative,
    UnknownFeaturesError,
    action_feature_index,
    feature_dim,
    get_features,
)
from neuronsmae.trainers.core.learner import EnvSpec, agent_spec

ABSTRACT_2V2: dict[str, Any] = {
    "n_actions": 8, "n_agents": 2, "state_shape": 21, "obs_shape": 37, "episode_limit": 50,
    "action_space": "abstract", "agents": ["blue_0", "blue_1"], "n_enemies": 2,
    "decision_steps": 20, "mode": "cooperative", "team_size": 2, "k": 4,
    "candidate_obs": True, "vector_obs": True, "lidar_beams": 0,
}  # fmt: skip
INFO = EnvInfo.from_dict(ABSTRACT_2V2)


def _obs(
    me: tuple[float, float, float], enemy0: tuple[float, float, float], point00: tuple[float, float]
) -> np.ndarray:
    """A 37-value observation with the given poses (metres, radians)."""
    o = np.zeros(37, np.float32)
    o[0:3] = [(me[0] - 4.04) / 4.04, (me[1] - 2.24) / 2.24, me[2] / np.pi]
    o[6:9] = [(enemy0[0] - 4.04) / 4.04, (enemy0[1] - 2.24) / 2.24, enemy0[2] / np.pi]
    o[12:14] = [(point00[0] - 4.04) / 4.04, (point00[1] - 2.24) / 2.24]
    return o


def test_relative_geometry_by_hand() -> None:
    # me at (1, 1) facing +x; enemy 0 at (4, 1) facing +x (its back towards me);
    # candidate point 0 of enemy 0 at (1.5, 1): behind the enemy.
    o = _obs((1.0, 1.0, 0.0), (4.0, 1.0, 0.0), (1.5, 1.0))
    f = get_features("relative", INFO)(o[None])[0]
    assert f.shape == (81,) and np.array_equal(f[:37], o)
    d_me_enemy, _, cos_bearing, sin_bearing, cos_seen, _ = f[37:43]
    assert d_me_enemy == pytest.approx(3.0 / 8.0, abs=1e-5)
    assert (cos_bearing, sin_bearing) == pytest.approx((1.0, 0.0), abs=1e-5)  # dead ahead
    assert cos_seen == pytest.approx(-1.0, abs=1e-5)  # I am behind the enemy
    d_point, _, cos_side, _ = f[43:47]
    assert d_point == pytest.approx(0.5 / 8.0, abs=1e-5)
    assert cos_side == pytest.approx(-1.0, abs=1e-5)  # the point faces its rear plate


def test_the_2v2_columns_are_the_released_layouts() -> None:
    """The points head of a 2 v 2 reads the same columns as when they were written down."""
    rows = action_feature_index("relative", INFO)
    for a, row in enumerate(rows):
        j, k = divmod(a, 4)
        base = 37 + 22 * j
        point = [12 + 2 * (4 * j + k), 13 + 2 * (4 * j + k)]
        enemy = [6 + 3 * j, 7 + 3 * j, 8 + 3 * j, 31 + j, 35 + j]
        relative = [*range(base, base + 6), *range(base + 6 + 4 * k, base + 10 + 4 * k)]
        assert row.tolist() == point + enemy + relative
    assert Relative(INFO).width == 81 and feature_dim("relative", INFO) == 81


@pytest.mark.parametrize(("team", "enemies", "k"), [(1, 1, 4), (3, 2, 3), (2, 3, 2)])
def test_relative_distances_follow_the_layout_for_any_team_sizes(
    team: int, enemies: int, k: int
) -> None:
    n = team + enemies
    info = EnvInfo.from_dict(
        {**ABSTRACT_2V2, "team_size": team, "n_agents": team, "n_enemies": enemies, "k": k,
         "agents": [f"blue_{i}" for i in range(team)], "n_actions": enemies * k,
         "obs_shape": 3 * n + 2 * k * enemies + 1 + 2 * n, "state_shape": 5 * n + 1}
    )  # fmt: skip
    rng = np.random.default_rng(team * 10 + enemies)
    obs = rng.uniform(-1, 1, (5, info.obs_shape)).astype(np.float32)
    relative = Relative(info)
    f = relative(obs)
    assert f.shape == (5, info.obs_shape + enemies * (4 + team + k * (2 + team)))
    metres = np.stack([obs[:, 0::3][:, :n] * 4.04 + 4.04, obs[:, 1::3][:, :n] * 2.24 + 2.24], -1)
    for j in range(enemies):
        cols = list(relative.enemy_columns(j))
        for mate in range(team):  # distances from me and each team-mate, in order
            d = np.linalg.norm(metres[:, team + j] - metres[:, mate], axis=-1) / 8.0
            np.testing.assert_allclose(f[:, cols[mate]], d, atol=1e-5)
        px, py = info.obs.point(j, k - 1)
        point = np.stack([obs[:, px] * 4.04 + 4.04, obs[:, py] * 2.24 + 2.24], -1)
        d = np.linalg.norm(point - metres[:, 0], axis=-1) / 8.0
        np.testing.assert_allclose(f[:, relative.point_columns(j, k - 1)[0]], d, atol=1e-5)


def test_registry_and_layout_errors() -> None:
    assert feature_dim("raw", INFO) == 37
    with pytest.raises(UnknownFeaturesError, match="valid: raw, relative"):
        get_features("polar", INFO)
    discrete = EnvInfo.from_dict(
        {**ABSTRACT_2V2, "action_space": "discrete", "n_actions": 10, "candidate_obs": False,
         "obs_shape": 21}
    )  # fmt: skip
    with pytest.raises(UnknownFeaturesError, match="candidate points in the observation"):
        get_features("relative", discrete)
    with pytest.raises(UnknownFeaturesError, match="expect 37 values, got 21"):
        Relative(INFO)(np.zeros((2, 21), np.float32))


def test_points_head_scores_each_action_from_its_own_point() -> None:
    env = EnvSpec.of(INFO, "relative")
    spec = agent_spec(env, 16, True, True, "relative", "points", INFO)
    agent = spec.build()
    with torch.no_grad():  # make the GRU blind to the input and the flat head silent
        agent.fc1.weight.zero_()
        agent.fc2.weight.zero_()
        agent.fc2.bias.zero_()
    x = torch.randn(1, 1, spec.input_dim)
    idx = action_feature_index("relative", INFO)
    swapped = x.clone()
    swapped[..., idx[0]], swapped[..., idx[1]] = x[..., idx[1]], x[..., idx[0]]
    q, _ = agent(x, agent.initial_hidden(1))
    q_swapped, _ = agent(swapped, agent.initial_hidden(1))
    assert q_swapped[0, 0, 0].item() == pytest.approx(q[0, 0, 1].item(), abs=1e-6)
    assert q_swapped[0, 0, 1].item() == pytest.approx(q[0, 0, 0].item(), abs=1e-6)
    with pytest.raises(UnknownFeaturesError, match="points"):
        action_feature_index("raw", INFO)
    with pytest.raises(UnknownFeaturesError, match="need the environment's layout"):
        agent_spec(env, 16, True, True, "relative", "points").build()
