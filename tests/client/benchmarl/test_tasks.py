"""The NeuronsMAE task family in BenchMARL (``neuronsmae.client.benchmarl.tasks``): each task's
environment passes TorchRL's ``check_env_specs`` and gives BenchMARL what its algorithms read
(group map, masks, state, ``max_steps``), configurations are checked, environments are seeded
one apart, and BenchMARL's Hydra loader finds the tasks."""

from __future__ import annotations

import numpy as np
import pytest

pytestmark = [
    pytest.mark.interop,
    pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning"),
]

pytest.importorskip("benchmarl")
utils = pytest.importorskip("torchrl.envs.utils")

from neuronsmae.client.benchmarl import NeuronsMAEClass, NeuronsMAETask  # noqa: E402
from neuronsmae.client.benchmarl.tasks import CONF, face_of  # noqa: E402
from neuronsmae.protocol.errors import InvalidOptionError  # noqa: E402

SHAPES = {  # task: (robots, actions per robot: a count for categorical, 4 for continuous rows)
    "COOP_ABSTRACT": (2, 8),
    "COOP_DISCRETE": (2, 10),
    "COOP_CONTINUOUS": (2, 4),
    "COOP_3V3": (3, 12),
}


def in_process(task: NeuronsMAETask, **config: object) -> NeuronsMAEClass:
    """The task with its YAML defaults and its arenas in process."""
    return task.get_task({**task.get_from_yaml().config, "env": "inprocess", **config})


@pytest.mark.parametrize("task", list(NeuronsMAETask), ids=lambda t: t.name.lower())
def test_every_task_passes_check_env_specs(task: NeuronsMAETask) -> None:
    built = in_process(task)
    continuous = built.supports_continuous_actions()
    assert continuous == (task is NeuronsMAETask.COOP_CONTINUOUS)
    assert built.supports_discrete_actions() != continuous
    env = built.get_env_fun(1, continuous, 0, "cpu")()
    try:
        utils.check_env_specs(env)
        robots, per = SHAPES[task.name]
        assert built.group_map(env) == {"blue": [f"blue_{i}" for i in range(robots)]}
        assert built.max_steps(env) == face_of(env).layout.episode_limit
        assert list(built.observation_spec(env).keys(True, True)) == [("blue", "observation")]
        assert built.state_spec(env)["state"].shape == (5 * 2 * robots + 1,)
        info = built.info_spec(env)["blue", "info"]
        assert {"battle_won", "episode_limit"} <= set(info.keys())
        masks = built.action_mask_spec(env)
        action = built.action_spec(env)["blue", "action"]
        if continuous:
            assert masks is None and action.shape == (robots, 4)
            assert "target_mask" in set(info.keys())
        else:
            assert masks["blue", "action_mask"].shape == (robots, per)
            assert action.shape == (robots,) and action.space.n == per
    finally:
        env.close()


def test_the_yaml_defaults_are_the_issue_s_tasks() -> None:
    paper = NeuronsMAETask.COOP_ABSTRACT.get_from_yaml()
    assert paper.config == {
        "env": None,
        "level": "easy",
        "contexts": {},
        "options": {"action_space": "abstract", "n_blue": 2, "n_red": 2},
    }
    assert NeuronsMAETask.COOP_3V3.get_task().settings.options["n_red"] == 3
    assert sorted(p.stem for p in (CONF / "task" / "neuronsmae").glob("*.yaml")) == sorted(
        t.name.lower() for t in NeuronsMAETask
    )


@pytest.mark.parametrize(
    ("config", "names"),
    [
        ({"n_blue": 3}, ["n_blue", "valid fields"]),
        ({"options": {"mode": "competitive"}}, ["mode", "cooperative"]),
        ({"options": {"action_space": "joystick"}}, ["action_space", "continuous"]),
        ({"options": {"max_cycles": 10}}, ["max_cycles", "episode_steps"]),
        ({"env": "Arena"}, ["env", "inprocess"]),
        ({"level": "expert"}, ["level", "hard"]),
        ({"contexts": {"level": "hard"}}, ["contexts['level']", "level"]),
        ({"contexts": [1]}, ["contexts", "dict"]),
    ],
)
def test_a_bad_config_is_refused_naming_the_field(config: dict, names: list[str]) -> None:
    with pytest.raises(InvalidOptionError) as caught:
        NeuronsMAETask.COOP_ABSTRACT.get_task(config)
    for name in names:
        assert name in str(caught.value)


def test_a_task_refuses_the_other_action_type() -> None:
    with pytest.raises(InvalidOptionError, match="continuous_actions=True"):
        in_process(NeuronsMAETask.COOP_ABSTRACT).get_env_fun(1, True, 0, "cpu")


def test_environments_of_one_factory_are_seeded_one_apart() -> None:
    make = in_process(NeuronsMAETask.COOP_ABSTRACT).get_env_fun(2, False, 7, "cpu")
    first, second = make(), make()
    again = in_process(NeuronsMAETask.COOP_ABSTRACT).get_env_fun(1, False, 8, "cpu")()
    try:
        obs = [e.reset()["blue", "observation"].numpy() for e in (first, second, again)]
        assert not np.array_equal(obs[0], obs[1])
        # reset() after construction continues the arena's RNG, so compare fresh envs built
        # the same way: the second of seed 7 is the first of seed 8
        assert np.array_equal(obs[1], obs[2])
    finally:
        for env in (first, second, again):
            env.close()


def test_log_info_reports_the_win_rate_of_finished_episodes() -> None:
    built = in_process(NeuronsMAETask.COOP_ABSTRACT, options={"episode_steps": 100})
    env = built.get_env_fun(1, False, 0, "cpu")()
    try:
        rollout = env.rollout(20, break_when_any_done=False)  # 5-decision episodes
        logged = built.log_info(rollout)
        won = rollout["next", "blue", "info", "battle_won"][rollout["next", "done"].squeeze(-1)]
        assert logged["collection/info/win_rate"] == pytest.approx(won[:, 0].float().mean())
        assert 0.0 <= logged["collection/info/episode_limit_rate"] <= 1.0
        # blue's own figures: its two robots' HP dealt and lost, not an average over four
        ended = rollout["next", "blue", "info"][rollout["next", "done"].squeeze(-1)]
        dealt = ended["damage_dealt"][:, 0, :2].sum(-1).double().mean()
        taken = ended["damage_taken"][:, 0, :2].sum(-1).double().mean()
        assert logged["collection/info/blue_damage_dealt"] == pytest.approx(float(dealt))
        assert logged["collection/info/blue_damage_taken"] == pytest.approx(float(taken))
        hp = ended["hp_fraction"][:, 0, :2].double().mean()
        assert logged["collection/info/blue_hp_left"] == pytest.approx(float(hp))
        assert 0.0 <= logged["collection/info/blue_bullets_left"] <= 1.0
    finally:
        env.close()


@pytest.mark.filterwarnings("ignore:TaskConfig python dataclass not found:UserWarning")
def test_benchmarl_s_hydra_config_takes_the_tasks_from_the_search_path() -> None:
    """What ``python -m neuronsmae.client.benchmarl.run`` hands BenchMARL's Hydra main."""
    from benchmarl.hydra_config import load_task_config_from_hydra
    from hydra import compose, initialize_config_module

    with initialize_config_module(version_base=None, config_module="benchmarl.conf"):
        cfg = compose(
            config_name="config",
            overrides=[
                "algorithm=mappo",
                "task=neuronsmae/coop_continuous",
                "task.level=middle",
                f"hydra.searchpath=[file://{CONF}]",
            ],
            return_hydra_config=True,
        )
    name = cfg.hydra.runtime.choices.task
    task = load_task_config_from_hydra(cfg.task, name)
    assert name == "neuronsmae/coop_continuous"
    assert isinstance(task, NeuronsMAEClass) and task.name == "COOP_CONTINUOUS"
    assert task.config["level"] == "middle" and task.supports_continuous_actions()


def test_a_config_changed_in_place_is_read_and_checked() -> None:
    """BenchMARL's examples change ``task.config`` after loading the YAML defaults."""
    task = NeuronsMAETask.COOP_ABSTRACT.get_from_yaml()
    task.config["options"]["action_space"] = "continuous"
    task.config["level"] = "middle"
    assert task.supports_continuous_actions() and task.settings.level == "middle"
    task.config["options"]["mode"] = "competitive"
    with pytest.raises(InvalidOptionError, match="mode"):
        task.get_env_fun(1, True, 0, "cpu")
