"""The task from the config: arena options, the learning team's view, the auto learner."""

from __future__ import annotations

from typing import Any

import pytest

from neuronsmae.protocol import EnvInfo
from neuronsmae.server import Arena
from neuronsmae.trainers.play.task import ArenaGroup, blue_view
from neuronsmae.trainers.run.config import ConfigError, make_config
from neuronsmae.trainers.run.config_groups import resolve_learner


def _info(**options: Any) -> EnvInfo:
    arena = Arena(seed=0, **options)
    try:
        return EnvInfo.from_dict(arena.get_env_info())
    finally:
        arena.close()


def test_arena_options_come_from_the_group() -> None:
    cfg = make_config({"n_blue": 3, "observability": "partial", "options": "k=6;episode_steps=500"})
    assert cfg.arena.arena_options("cooperative") == {
        "action_space": "abstract", "n_blue": 3, "n_red": 2, "observability": "partial",
        "lidar": False, "vector_obs": True, "reward": "dense", "spawn": "random", "k": 6,
        "episode_steps": 500, "mode": "cooperative",
    }  # fmt: skip


def test_continuous_actions_are_refused_naming_what_works() -> None:
    with pytest.raises(ConfigError, match=r"Q-learners .*valid: abstract, discrete"):
        ArenaGroup(action_space="continuous")
    with pytest.raises(ConfigError, match=r"valid: abstract, discrete"):
        blue_view(_info(action_space="continuous"))


def test_the_competitive_task_is_seen_from_blue() -> None:
    info = _info(mode="competitive", n_blue=3, n_red=3)
    view = blue_view(info)
    assert (info.n_agents, view.n_agents) == (6, 3)
    assert view.agents == ("blue_0", "blue_1", "blue_2") and view.obs_shape == info.obs_shape


@pytest.mark.parametrize(
    ("options", "observability_spawn", "want"),
    [
        ({}, ("full", "random"), ("relative", "points", "enemies,field,allies")),
        ({"action_space": "discrete"}, ("full", "random"), ("raw", "flat", "enemies,field,allies")),
        ({"n_blue": 3, "n_red": 3}, ("full", "random"), ("relative", "points", "field")),
        ({"n_blue": 1, "n_red": 1}, ("full", "random"), ("relative", "points", "field")),
        ({"n_blue": 3, "n_red": 2}, ("full", "random"), ("relative", "points", "enemies,field")),
        ({"observability": "partial"}, ("partial", "random"), ("relative", "points",
                                                               "enemies,allies")),
        ({"spawn": "corners"}, ("full", "corners"), ("relative", "points", "enemies,allies")),
        ({"candidate_obs": False}, ("full", "random"), ("raw", "flat", "enemies,allies")),
        ({"lidar": True}, ("full", "random"), ("relative", "points", "none")),
        ({"lidar": True, "vector_obs": False}, ("full", "random"), ("raw", "flat", "none")),
        ({"mode": "competitive"}, ("full", "random"), ("relative", "points", "none")),
    ],
)  # fmt: skip
def test_auto_learner_settings_fit_every_variant(
    options: dict[str, Any], observability_spawn: tuple[str, str], want: tuple[str, str, str]
) -> None:
    view = blue_view(_info(**options))
    lc = resolve_learner(make_config().learner, view, *observability_spawn)
    assert (lc.features, lc.head, lc.augment) == want


def test_explicit_settings_are_kept_or_refused_where_the_task_lacks_the_symmetry() -> None:
    view = blue_view(_info())
    raw = make_config({"features": "raw", "head": "flat", "augment": "none"}).learner
    assert resolve_learner(raw, view, "full", "random") == raw
    field = make_config({"augment": "field"}).learner
    with pytest.raises(ConfigError, match=r"'field'.*observability='partial'"):
        resolve_learner(field, view, "partial", "random")
