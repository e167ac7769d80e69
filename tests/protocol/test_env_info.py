"""EnvInfo parses the env-info dict in one place, with typed errors, and lays it out."""

from __future__ import annotations

import re

import pytest

from neuronsmae.protocol import EnvInfo, EnvInfoError

ABSTRACT_2V2 = {
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
    "team_size": 2,
    "k": 4,
    "candidate_obs": True,
    "vector_obs": True,
    "lidar_beams": 0,
}


def test_the_released_37_value_layout_by_name() -> None:
    info = EnvInfo.from_dict(ABSTRACT_2V2)
    obs = info.obs
    assert [obs.pose(r) for r in range(4)] == [(0, 1, 2), (3, 4, 5), (6, 7, 8), (9, 10, 11)]
    assert obs.enemy(0) == 2 and obs.point(0, 0) == (12, 13) and obs.point(1, 3) == (26, 27)
    assert obs.time == slice(28, 29)
    assert [obs.hp_of(r) for r in range(4)] == [29, 30, 31, 32]
    assert [obs.bullets_of(r) for r in range(4)] == [33, 34, 35, 36]
    assert obs.lidar == slice(37, 37) and obs.size == 37
    assert obs.xy_columns() == [0, 1, 3, 4, 6, 7, 9, 10, *range(12, 28)]
    assert obs.yaw_columns() == [2, 5, 8, 11]
    state = info.state
    assert state.pose(2) == (10, 11, 12) and state.hp_of(1) == 8 and state.time == 20
    assert info.action(1, 2) == 6 and info.split(6) == (1, 2) and info.actions_per_enemy == 4
    assert info.motion_bounds == ((-2.0, -2.0, -1.75), (2.0, 2.0, 1.75))


def test_unknown_keys_are_ignored_and_agents_become_a_tuple() -> None:
    info = EnvInfo.from_dict({**ABSTRACT_2V2, "added_by_a_newer_server": 1})
    assert info.agents == ("blue_0", "blue_1")
    assert info.to_dict() == ABSTRACT_2V2


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"k": None}, "env info lacks k; it needs n_actions, "),
        ({"obs_shape": "37"}, "obs_shape='37' must be int"),
        ({"n_agents": True}, "n_agents=True must be int"),
        ({"agents": ["blue_0", 1]}, "must be a list of str"),
        ({"vector_obs": 1}, "vector_obs=1 must be bool"),
        ({"obs_shape": 36}, "obs_shape=36 does not fit the layout, which gives 37"),
        ({"state_shape": 20}, "state_shape=20 does not fit the layout, which gives 21"),
        ({"n_actions": 10}, "n_actions=10 does not fit the layout, which gives 8"),
        ({"action_space": "joystick"}, "action_space='joystick'; valid: abstract, discrete"),
        ({"agents": ["blue_0"]}, "2 agents but 1 names"),
    ],
)
def test_bad_dicts_raise_typed_errors_naming_the_key(change: dict, message: str) -> None:
    info = {**ABSTRACT_2V2, **change}
    info = {k: v for k, v in info.items() if v is not None}
    with pytest.raises(EnvInfoError, match=re.escape(message)):
        EnvInfo.from_dict(info)


def test_absent_blocks_and_indices_out_of_range_are_errors() -> None:
    lidar_only = EnvInfo.from_dict({**ABSTRACT_2V2, "vector_obs": False, "lidar_beams": 61,
                                    "obs_shape": 61})  # fmt: skip
    assert lidar_only.obs.lidar == slice(0, 61) and lidar_only.obs.xy_columns() == []
    with pytest.raises(EnvInfoError, match="no poses"):
        lidar_only.obs.pose(0)
    discrete = EnvInfo.from_dict({**ABSTRACT_2V2, "action_space": "discrete", "n_actions": 10,
                                  "candidate_obs": False, "obs_shape": 21})  # fmt: skip
    assert discrete.obs.time == slice(12, 13) and discrete.actions_per_enemy == 5
    with pytest.raises(EnvInfoError, match="no candidate points"):
        discrete.obs.point(0, 0)
    info = EnvInfo.from_dict(ABSTRACT_2V2)
    with pytest.raises(EnvInfoError, match=re.escape("enemy 2 is out of range; valid: 0..1")):
        info.obs.enemy(2)
    with pytest.raises(EnvInfoError, match=re.escape("action 8 is out of range; valid: 0..7")):
        info.split(8)
    with pytest.raises(EnvInfoError, match="must be a mapping"):
        EnvInfo.from_dict([("n_agents", 2)])  # type: ignore[arg-type]
