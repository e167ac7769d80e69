"""Derived input features: the raw observation is kept and the geometry is right."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuronsmae.trainers.features import (
    UnknownFeaturesError,
    action_feature_index,
    feature_dim,
    get_features,
    relative,
)
from neuronsmae.trainers.learner import EnvSpec, agent_spec


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
    f = relative(o[None])[0]
    assert f.shape == (81,) and np.array_equal(f[:37], o)
    d_me_enemy, _, cos_bearing, sin_bearing, cos_seen, _ = f[37:43]
    assert d_me_enemy == pytest.approx(3.0 / 8.0, abs=1e-5)
    assert (cos_bearing, sin_bearing) == pytest.approx((1.0, 0.0), abs=1e-5)  # dead ahead
    assert cos_seen == pytest.approx(-1.0, abs=1e-5)  # I am behind the enemy
    d_point, _, cos_side, _ = f[43:47]
    assert d_point == pytest.approx(0.5 / 8.0, abs=1e-5)
    assert cos_side == pytest.approx(-1.0, abs=1e-5)  # the point faces its rear plate


def test_registry_and_layout_errors() -> None:
    assert feature_dim("raw", 21) == 21 and feature_dim("relative", 37) == 81
    with pytest.raises(UnknownFeaturesError, match="valid: raw, relative"):
        get_features("polar")
    with pytest.raises(UnknownFeaturesError, match="37-value"):
        relative(np.zeros((2, 21), np.float32))


def test_points_head_scores_each_action_from_its_own_point() -> None:
    env = EnvSpec(n_agents=2, n_actions=8, obs_dim=81, state_dim=21, episode_limit=50)
    spec = agent_spec(env, 16, True, True, "relative", "points")
    agent = spec.build()
    with torch.no_grad():  # make the GRU blind to the input and the flat head silent
        agent.fc1.weight.zero_()
        agent.fc2.weight.zero_()
        agent.fc2.bias.zero_()
    x = torch.randn(1, 1, spec.input_dim)
    idx = action_feature_index("relative", 8)
    swapped = x.clone()
    swapped[..., idx[0]], swapped[..., idx[1]] = x[..., idx[1]], x[..., idx[0]]
    q, _ = agent(x, agent.initial_hidden(1))
    q_swapped, _ = agent(swapped, agent.initial_hidden(1))
    assert q_swapped[0, 0, 0].item() == pytest.approx(q[0, 0, 1].item(), abs=1e-6)
    assert q_swapped[0, 0, 1].item() == pytest.approx(q[0, 0, 0].item(), abs=1e-6)
    with pytest.raises(UnknownFeaturesError, match="points"):
        action_feature_index("raw", 8)
