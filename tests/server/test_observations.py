"""Observation layouts index by index, partial observability, LiDAR and the global state."""

from __future__ import annotations

import functools
import operator

import numpy as np
import pytest

from neuronsmae.server import Arena

SCENE = np.array([(1.0, 1.0, 0.5), (2.0, 3.5, -1.0), (6.0, 1.2, np.pi), (7.0, 3.6, 2.0)])


def _scene(**options) -> tuple[Arena, list[np.ndarray]]:
    a = Arena(seed=1, mode="competitive", **options)
    a.reset()
    obs = a.place(SCENE, bullets=[370, 200, 100, 0])
    return a, obs


def _pose(i: int) -> list[float]:
    x, y, yaw = SCENE[i]
    yaw = (yaw + np.pi) % (2 * np.pi) - np.pi  # wrapped to [-π, π): π reads as -1
    return [(x - 4.04) / 4.04, (y - 2.24) / 2.24, yaw / np.pi]


def test_abstract_layout_37_index_by_index() -> None:
    a, obs = _scene(action_space="abstract")
    assert a.get_env_info()["obs_shape"] == 37
    o = obs[0]  # blue_0: self 0, ally 1, enemies 2, 3
    assert o.shape == (37,) and o.dtype == np.float32
    np.testing.assert_allclose(
        o[0:12], functools.reduce(operator.iadd, (_pose(i) for i in (0, 1, 2, 3)), []), atol=1e-6
    )
    cands = a.cands[0]  # (2 enemies, 4 points, 2)
    expect = np.stack([(cands[..., 0] - 4.04) / 4.04, (cands[..., 1] - 2.24) / 2.24], -1)
    np.testing.assert_allclose(o[12:28], expect.reshape(-1), atol=1e-6)
    assert o[28] == pytest.approx(-1.0)  # t = 0
    np.testing.assert_allclose(o[29:33], [1.0, 1.0, 1.0, 1.0])
    np.testing.assert_allclose(
        o[33:37], [1.0, 2 * 200 / 370 - 1, 2 * 100 / 370 - 1, -1.0], atol=1e-6
    )
    # red_1 sees itself first, its ally red_0, then blue_0 and blue_1.
    np.testing.assert_allclose(
        obs[3][0:12],
        functools.reduce(operator.iadd, (_pose(i) for i in (3, 2, 0, 1)), []),
        atol=1e-6,
    )
    np.testing.assert_allclose(
        obs[3][33:37], [-1.0, 2 * 100 / 370 - 1, 1.0, 2 * 200 / 370 - 1], atol=1e-6
    )
    a.close()


def test_discrete_layout_21_index_by_index() -> None:
    a, obs = _scene(action_space="discrete")
    assert a.get_env_info()["obs_shape"] == 21
    o = obs[1]  # blue_1: self 1, ally 0, enemies 2, 3
    np.testing.assert_allclose(
        o[0:12], functools.reduce(operator.iadd, (_pose(i) for i in (1, 0, 2, 3)), []), atol=1e-6
    )
    assert o[12] == pytest.approx(-1.0)
    np.testing.assert_allclose(o[13:17], [1.0] * 4)
    np.testing.assert_allclose(
        o[17:21], [2 * 200 / 370 - 1, 1.0, 2 * 100 / 370 - 1, -1.0], atol=1e-6
    )
    a.close()


def test_time_and_hp_normalisation_after_a_step() -> None:
    a, _ = _scene(action_space="discrete")
    obs, *_ = a.step([0, 0, 0, 0])
    assert obs[0][12] == pytest.approx(2 * 5 / 1000 - 1)
    assert (np.abs(np.stack(obs)) <= 1.0).all()
    a.close()


@pytest.mark.parametrize("n", [1, 2, 3])
def test_layout_formula_for_team_sizes(n: int) -> None:
    a = Arena(seed=1, n_blue=n, n_red=n, action_space="abstract", k=3)
    obs = a.reset()
    expect = 3 * 2 * n + 2 * 3 * n + 1 + 2 * 2 * n
    assert a.get_env_info()["obs_shape"] == expect == obs[0].shape[0]
    a.close()


@pytest.mark.parametrize("n_blue,n_red", [(3, 2), (2, 1), (3, 1), (1, 3)])
@pytest.mark.parametrize("observability", ["full", "partial"])
def test_unequal_teams_follow_the_layout_formula(
    n_blue: int, n_red: int, observability: str
) -> None:
    # The learning team's vectors, masks and state stay sized by its own enemy count even
    # when the other team is larger or smaller (sight and candidates are computed for all).
    a = Arena(seed=1, n_blue=n_blue, n_red=n_red, observability=observability)
    obs = a.reset()
    info = a.get_env_info()
    assert info["obs_shape"] == 3 * (n_blue + n_red) + 2 * 4 * n_red + 1 + 2 * (n_blue + n_red)
    assert info["n_actions"] == 4 * n_red
    for _ in range(5):
        masks = a.get_avail_actions()
        assert [m.shape for m in masks] == [(info["n_actions"],)] * n_blue
        assert all(o.shape == (info["obs_shape"],) for o in obs)
        assert a.get_state().shape == (info["state_shape"],)
        obs, _, done, _ = a.step([int(np.flatnonzero(m)[-1]) for m in masks])
        if done:
            break
    a.close()


def test_state_is_global_not_an_observation() -> None:
    a, _ = _scene(action_space="abstract", observability="partial")
    s = a.get_state()
    assert s.shape == (a.get_env_info()["state_shape"],) == (21,)
    np.testing.assert_allclose(s[0:3], _pose(0), atol=1e-6)
    np.testing.assert_allclose(s[15:18], _pose(3), atol=1e-6)
    assert s[-1] == pytest.approx(-1.0)
    a.close()


def test_partial_observability_hides_enemy_behind_tall_obstacle() -> None:
    # blue_0 below B5 looking up at red_0 above it: hidden by the wall; red_1 in plain view.
    scene = np.array(
        [(4.04, 2.6, np.pi / 2), (0.6, 0.6, 0.0), (4.04, 4.1, -np.pi / 2), (4.9, 3.0, np.pi)]
    )
    a = Arena(
        seed=1,
        mode="competitive",
        action_space="discrete",
        observability="partial",
        camera_hfov_deg=120.0,
    )
    a.reset()
    obs = a.place(scene)
    o = obs[0]
    np.testing.assert_allclose(o[6:9], [-1.0, -1.0, -1.0])  # red_0 padded
    assert not np.allclose(o[9:12], -1.0)  # red_1 seen
    hidden = [(4.04 - 4.04) / 4.04, (4.1 - 2.24) / 2.24, -0.5]  # red_0's pose, normalised
    np.testing.assert_allclose(a.get_state()[10:13], hidden, atol=1e-6)  # the state is global
    # With full observability the same scene shows both.
    b = Arena(seed=1, mode="competitive", action_space="discrete")
    b.reset()
    full = b.place(scene)[0]
    np.testing.assert_allclose(full[6:9], hidden, atol=1e-6)
    a.close()
    b.close()


def test_partial_observability_low_obstacle_and_field_of_view() -> None:
    # Across B6 (low): seen when the gimbal faces it; not seen when it is outside the view.
    scene = np.array(
        [(1.9, 1.5, np.pi / 2), (0.6, 0.6, 0.0), (1.9, 3.0, -np.pi / 2), (7.4, 0.6, np.pi)]
    )
    a = Arena(seed=1, mode="competitive", action_space="discrete", observability="partial")
    a.reset()
    obs = a.place(scene)  # blue_0's target is the nearest enemy, red_0, straight ahead
    assert not np.allclose(obs[0][6:9], -1.0)
    np.testing.assert_allclose(obs[0][9:12], [-1.0, -1.0, -1.0])  # red_1 far behind-right
    a.close()


def test_lidar_beam_toward_wall_returns_its_distance() -> None:
    a = Arena(
        seed=1,
        mode="competitive",
        action_space="discrete",
        lidar=True,
        vector_obs=False,
        lidar_range=8.0,
    )
    a.reset()
    # blue_0 at (1.0, 1.9) facing -x: the front beam hits the left wall 1.0 m away.
    obs = a.place(
        np.array([(1.0, 1.9, np.pi), (0.6, 3.9, 0.0), (7.4, 3.9, np.pi), (7.5, 0.6, np.pi)])
    )
    assert obs[0].shape == (61,)
    front = (obs[0][30] + 1) / 2 * 8.0
    assert front == pytest.approx(1.0, abs=1e-5)
    # The beam at +90° (left of a robot facing -x points to -y) hits the bottom wall at 1.9 m.
    left = (obs[0][50] + 1) / 2 * 8.0
    assert left == pytest.approx(1.9, abs=1e-5)
    a.close()


def test_lidar_sees_robots_and_combines_with_vector() -> None:
    a = Arena(seed=1, mode="competitive", action_space="abstract", lidar=True)
    a.reset()
    obs = a.place(
        np.array([(1.0, 1.9, 0.0), (2.0, 1.9, 0.0), (7.4, 3.9, np.pi), (7.5, 0.6, np.pi)])
    )
    assert obs[0].shape == (37 + 61,) == (a.get_env_info()["obs_shape"],)
    front = (obs[0][37 + 30] + 1) / 2 * 8.0
    assert front == pytest.approx(2.0 - 0.3 - 1.0, abs=1e-5)  # blue_1's rear face
    a.close()
