"""Derived input features: the raw observation is kept and the geometry is right."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuronsmae.server.sim.field import OBSTACLES
from neuronsmae.trainers.features import (
    EXPOSURE_DIM,
    RELATIVE_DIM,
    SIGHT_BOXES,
    UnknownFeaturesError,
    action_feature_index,
    exposure,
    feature_dim,
    get_features,
    relative,
    sight,
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


def test_exposure_describes_what_each_point_offers_the_other_enemy() -> None:
    # Target enemy 0 at (4, 1); its point 0 at (1.5, 1), so standing there I face +x.
    # Enemy 1 at (1.5, 3) facing -y: 2 m to my left (my side plate), and I am dead ahead
    # of it (inside its cone).
    o = _obs((1.0, 1.0, 0.0), (4.0, 1.0, 0.0), (1.5, 1.0))
    o[9:12] = [(1.5 - 4.04) / 4.04, (3.0 - 2.24) / 2.24, -0.5]
    f = exposure(o[None])[0]
    assert f.shape == (121,) and np.array_equal(f[:RELATIVE_DIM], relative(o[None])[0])
    d_other, cos_seen, sin_seen, cos_cone, sin_cone = f[RELATIVE_DIM : RELATIVE_DIM + 5]
    assert d_other == pytest.approx(2.0 / 8.0, abs=1e-5)
    assert (cos_seen, sin_seen) == pytest.approx((0.0, 1.0), abs=1e-5)  # on my left
    assert (cos_cone, sin_cone) == pytest.approx((1.0, 0.0), abs=1e-5)  # in its cone
    # Action 0's row of the points head ends with exactly these five columns.
    row = action_feature_index("exposure", 8)[0]
    assert list(row[-5:]) == list(range(RELATIVE_DIM, RELATIVE_DIM + 5))
    assert list(row[:-5]) == list(action_feature_index("relative", 8)[0])


def test_sight_tells_which_walls_stand_between_robots_and_points() -> None:
    # B4 is the tall wall at x 3.55-4.53, y 0.95-1.13. Me at (3, 1) and enemy 0 at (5, 1):
    # the wall is between us. Enemy 1 at (4, 2) sees over nothing tall to either of us.
    # Enemy 0's point 0 at (4, 0.5) is hidden from enemy 1 by B4; its point 1 at (5, 2)
    # is in plain view of enemy 1. My ally at (6, 1) sees enemy 0 (nothing between).
    o = _obs((3.0, 1.0, 0.0), (5.0, 1.0, np.pi), (4.0, 0.5))
    o[3:5] = [(6.0 - 4.04) / 4.04, (1.0 - 2.24) / 2.24]
    o[9:11] = [(4.0 - 4.04) / 4.04, (2.0 - 2.24) / 2.24]
    o[14:16] = [(5.0 - 4.04) / 4.04, (2.0 - 2.24) / 2.24]
    f = sight(o[None])[0]
    assert f.shape == (133,) and np.array_equal(f[:EXPOSURE_DIM], exposure(o[None])[0])
    enemy0, enemy1 = f[EXPOSURE_DIM : EXPOSURE_DIM + 6], f[EXPOSURE_DIM + 6 :]
    assert enemy0[:4].tolist() == [0.0, 1.0, 0.0, 1.0]  # me, ally, point 0 hidden, point 1 seen
    assert enemy1[:2].tolist() == [1.0, 1.0]
    # Action 1 (enemy 0, point 1) reads its own sight columns: me→enemy 0, ally→enemy 0,
    # point 1→enemy 1.
    row = action_feature_index("sight", 8)[1]
    assert list(row[-3:]) == [EXPOSURE_DIM, EXPOSURE_DIM + 1, EXPOSURE_DIM + 3]
    assert list(row[:-3]) == list(action_feature_index("exposure", 8)[1])


def test_sight_map_is_the_tall_obstacles_made_exactly_symmetric() -> None:
    tall = [o for o in OBSTACLES if o.tall]
    assert len(SIGHT_BOXES) == len(tall) == 6
    for o, box in zip(tall, SIGHT_BOXES, strict=True):  # within the layout's 2 cm
        assert box[:2] == pytest.approx([o.cx - o.sx / 2, o.cy - o.sy / 2], abs=0.02)
        assert box[2:] == pytest.approx([o.cx + o.sx / 2, o.cy + o.sy / 2], abs=0.02)
    lo_x, lo_y, hi_x, hi_y = SIGHT_BOXES.T  # half a turn about the centre swaps lo and hi
    turned = np.c_[8.08 - hi_x, 4.48 - hi_y, 8.08 - lo_x, 4.48 - lo_y]
    rows = np.unique(np.round(SIGHT_BOXES, 9), axis=0)
    assert np.array_equal(np.unique(np.round(turned, 9), axis=0), rows)


def test_registry_and_layout_errors() -> None:
    assert feature_dim("raw", 21) == 21 and feature_dim("relative", 37) == 81
    assert feature_dim("exposure", 37) == 121 and feature_dim("sight", 37) == 133
    with pytest.raises(UnknownFeaturesError, match="valid: exposure, raw, relative, sight"):
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
