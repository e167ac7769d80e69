"""TorchRL on the PettingZoo face, as a TorchRL user writes it: ``PettingZooWrapper`` around
``parallel_env()`` (a private served arena), ``check_env_specs``, rollouts whose infos reach
the tensordict from the reset on, and episodes that go on after the first robot is lost."""

from __future__ import annotations

import pytest

from neuronsmae.client import parallel_env
from neuronsmae.client.infos import ROBOT_KEYS, SCALAR_KEYS

pytestmark = [
    pytest.mark.interop,
    # TorchRL names the PettingZoo version it was tested with; that is not a finding.
    pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning"),
]

pettingzoo_lib = pytest.importorskip("torchrl.envs.libs.pettingzoo")
utils = pytest.importorskip("torchrl.envs.utils")

IN_PROCESS = "neuronsmae.server:Arena"
BLUE_LOSES = {"coef": 10.0, "opponent_hp": 10000.0}
"""Contexts under which red destroys blue robots one by one within a few decisions."""


def test_check_env_specs_passes_with_default_arguments() -> None:
    env = pettingzoo_lib.PettingZooWrapper(env=parallel_env(), use_mask=True)
    try:
        utils.check_env_specs(env)
        assert env.group_map == {"blue": ["blue_0", "blue_1"]}
        first = env.reset()
        # Reset infos carry the step infos' keys, so TorchRL puts them in its specs.
        info = first["blue", "info"]
        assert set(info.keys()) == {*SCALAR_KEYS, *ROBOT_KEYS}
        assert (info["t"] == 0).all()
        rollout = env.rollout(12, break_when_any_done=False)
        assert rollout["next", "blue", "info", "t"].shape == (12, 2)
        assert rollout["next", "blue", "action_mask"].shape == (12, 2, 8)
    finally:
        env.close()


def test_competitive_groups_and_an_episode_that_outlives_its_first_loss() -> None:
    competitive = parallel_env(env=IN_PROCESS, seed=0, mode="competitive", episode_steps=200)
    env = pettingzoo_lib.PettingZooWrapper(env=competitive, use_mask=True)
    try:
        utils.check_env_specs(env)
        assert set(env.group_map) == {"blue", "red"}
    finally:
        env.close()
    three = parallel_env(env=IN_PROCESS, seed=5, n_blue=3, n_red=3, episode_steps=3000,
                         contexts=BLUE_LOSES)  # fmt: skip
    env = pettingzoo_lib.PettingZooWrapper(env=three, use_mask=True)
    try:
        # TorchRL's default stops at the first "done": that must be the episode's end (blue
        # wiped out), not the first robot destroyed.
        rollout = env.rollout(150)
        dead = rollout["next", "blue", "info", "dead_allies"][:, 0]
        assert rollout["next", "done"][-1].all() and not rollout["next", "done"][:-1].any()
        assert dead[-1] == 3 and int((dead > 0).sum()) > 1  # robots were lost along the way
    finally:
        env.close()
