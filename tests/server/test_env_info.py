"""EnvInfo's layouts name the columns the arena actually fills, and survive the wire."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from neuronsmae.protocol import EnvInfo
from neuronsmae.protocol.codec import decode, encode
from neuronsmae.protocol.env_info import FIELD_HALF
from neuronsmae.server import Arena
from neuronsmae.server.task import observations as O
from neuronsmae.server.task import perception as P

OPTION_SETS: dict[str, dict[str, Any]] = {
    "1v1": {"n_blue": 1, "n_red": 1},
    "2v2": {},
    "3v3": {"n_blue": 3, "n_red": 3},
    "3v2": {"n_blue": 3, "n_red": 2},
    "discrete": {"action_space": "discrete"},
    "continuous": {"action_space": "continuous"},
    "partial": {"observability": "partial"},
    "lidar": {"lidar": True},
    "lidar-only": {"vector_obs": False, "lidar": True},
    "discrete-k3-points": {"action_space": "discrete", "k": 3, "candidate_obs": True},
    "competitive": {"mode": "competitive", "n_blue": 2, "n_red": 2},
}


def _norm_xy(xy: np.ndarray) -> np.ndarray:
    return O.norm_xy(np.asarray(xy, dtype=np.float64))


def _check_observations(arena: Arena, obs: list[np.ndarray]) -> None:
    """Every column the layout names holds what the arena's own state says it should."""
    info, cfg, ref = arena.env_info(), arena.config, arena.referee
    layout, unseen = info.obs, cfg.unseen_value
    poses = O.norm_pose(arena.poses)
    for a, i in enumerate(arena.agents):
        o = obs[a]
        assert o.shape == (layout.size,) == (info.obs_shape,)
        order = np.concatenate([arena.mates_of[i], arena.enemies_of[i]])
        for r, robot in enumerate(order if layout.vector else []):
            got = o[list(layout.pose(r))]
            hidden = r >= layout.team_size and np.all(got == unseen)
            if not (hidden and cfg.observability == "partial"):
                np.testing.assert_allclose(got, poses[robot], atol=1e-6)
            hp = 2.0 * ref.hp[robot] / ref.max_hp[robot] - 1.0
            assert o[layout.hp_of(r)] == pytest.approx(hp, abs=1e-6)
            bullets = O.norm_bullets(ref.bullets[robot], ref.max_bullets[robot])
            assert o[layout.bullets_of(r)] == pytest.approx(bullets, abs=1e-6)
        if layout.vector:
            time = O.norm_time(arena.t, cfg.episode_steps)
            assert o[layout.time.start] == pytest.approx(time, abs=1e-6)
        for j in range(layout.n_enemies if layout.k else 0):
            seen = not np.all(o[list(layout.pose(layout.enemy(j)))] == unseen)
            for q in range(layout.k):
                want = _norm_xy(arena.cands[i, j, q]) if seen else [unseen, unseen]
                np.testing.assert_allclose(o[list(layout.point(j, q))], want, atol=1e-6)
        if layout.lidar_beams:
            scan = P.lidar(arena.poses, i, cfg.lidar_range)
            np.testing.assert_allclose(o[layout.lidar], scan, atol=1e-6)


def _check_state(arena: Arena) -> None:
    state, layout, ref = arena.get_state(), arena.env_info().state, arena.referee
    assert state.shape == (layout.size,)
    poses = O.norm_pose(arena.poses)
    for r in range(arena.n):
        np.testing.assert_allclose(state[list(layout.pose(r))], poses[r], atol=1e-6)
        assert state[layout.hp_of(r)] == pytest.approx(2.0 * ref.hp[r] / ref.max_hp[r] - 1.0)
        assert state[layout.bullets_of(r)] == pytest.approx(
            O.norm_bullets(ref.bullets[r], ref.max_bullets[r])
        )
    assert state[layout.time] == pytest.approx(O.norm_time(arena.t, arena.config.episode_steps))


@pytest.mark.parametrize("options", OPTION_SETS.values(), ids=OPTION_SETS.keys())
def test_layout_names_the_columns_the_arena_fills(options: dict[str, Any]) -> None:
    arena = Arena(seed=3, **options)
    try:
        obs = arena.reset(seed=11)
        _check_observations(arena, obs)
        _check_state(arena)
        obs, _, _, _ = arena.step([_first(m, arena) for m in arena.get_avail_actions()])
        _check_observations(arena, obs)
        _check_state(arena)
    finally:
        arena.close()


def _first(mask: np.ndarray, arena: Arena) -> Any:
    """An available action: the last allowed index (continuous: drive and aim there)."""
    index = int(np.flatnonzero(mask)[-1])
    return [0.5, 0.0, 0.2, index] if arena.config.action_space == "continuous" else index


@pytest.mark.parametrize("options", OPTION_SETS.values(), ids=OPTION_SETS.keys())
def test_env_info_round_trips_through_the_wire(options: dict[str, Any]) -> None:
    arena = Arena(seed=0, **options)
    try:
        sent = arena.get_env_info()
        received = decode(encode(sent), max_bytes=1 << 20)
        info = EnvInfo.from_dict(received)
        assert info == arena.env_info()
        assert info.to_dict() == sent
        assert info.obs == arena.env_info().obs and info.state == arena.env_info().state
    finally:
        arena.close()


def test_the_wire_dict_keeps_the_released_keys_and_values() -> None:
    arena = Arena(seed=0)
    try:
        info = arena.get_env_info()
    finally:
        arena.close()
    released = {
        "n_actions": 8,
        "n_agents": 2,
        "state_shape": 21,
        "obs_shape": 37,
        "episode_limit": 50,
        "action_space": "abstract",
        "agents": ["blue_0", "blue_1"],
        "n_enemies": 2,
        "decision_steps": 20,
        "mode": "cooperative",
    }
    assert {k: info[k] for k in released} == released


def test_the_position_scale_is_the_fields() -> None:
    assert (O.HALF_X, O.HALF_Y) == FIELD_HALF
