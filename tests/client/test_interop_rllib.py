"""RLlib on the PettingZoo face, as an RLlib user writes it: ``ParallelPettingZooEnv``
around ``parallel_env(masks="rllib")`` (a private served arena per environment), RLlib's
action-masking PPO module reading the ``observations`` / ``action_mask`` keys, one shared
policy, one training iteration on a small local Ray."""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from neuronsmae.client import parallel_env

pytestmark = [pytest.mark.interop, pytest.mark.ray]

ray = pytest.importorskip("ray")
pytest.importorskip("ray.rllib")

from ray.rllib.algorithms.ppo import PPOConfig  # noqa: E402
from ray.rllib.core.rl_module.multi_rl_module import MultiRLModuleSpec  # noqa: E402
from ray.rllib.core.rl_module.rl_module import RLModuleSpec  # noqa: E402
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv  # noqa: E402
from ray.rllib.examples.rl_modules.classes.action_masking_rlm import (  # noqa: E402
    ActionMaskingTorchRLModule,
)
from ray.tune.registry import register_env  # noqa: E402

BATCH = 80
"""Environment steps in the one training batch (8 episodes of 10 decisions)."""


@pytest.fixture(scope="module")
def local_ray() -> Iterator[None]:
    ray.init(
        num_cpus=1, include_dashboard=False, log_to_driver=False, logging_level=logging.WARNING
    )
    yield
    ray.shutdown()


def make_env(config: dict[str, Any]) -> ParallelPettingZooEnv:
    return ParallelPettingZooEnv(parallel_env(masks="rllib", **config))


@pytest.mark.usefixtures("local_ray")
def test_one_ppo_iteration_with_action_masking() -> None:
    register_env("neuronsmae_masked", make_env)
    module = RLModuleSpec(module_class=ActionMaskingTorchRLModule,
                          model_config={"fcnet_hiddens": [32]})  # fmt: skip
    config = (
        PPOConfig()
        .environment("neuronsmae_masked", env_config={"episode_steps": 200})
        .env_runners(num_env_runners=0, rollout_fragment_length=BATCH // 2)
        .training(train_batch_size_per_learner=BATCH, minibatch_size=BATCH // 2, num_epochs=1)
        .multi_agent(policies={"shared"}, policy_mapping_fn=lambda *args, **kwargs: "shared")
        .rl_module(rl_module_spec=MultiRLModuleSpec(rl_module_specs={"shared": module}))
        .debugging(seed=0)
    )
    algo = config.build_algo()
    try:
        env = algo.env_runner.env.unwrapped.envs[0]  # type: ignore[union-attr]
        space = env.observation_space["blue_0"]
        assert set(space.spaces) == {"observations", "action_mask"}
        result = algo.train()
    finally:
        algo.stop()
    runners = result["env_runners"]
    assert runners["num_env_steps_sampled"] >= BATCH and runners["num_episodes"] >= 1
    assert runners["episode_len_max"] == 10 and math.isfinite(runners["episode_return_mean"])
    learner = result["learners"]["shared"]
    assert learner["num_module_steps_trained"] >= BATCH
    assert np.isfinite(learner["total_loss"]) and np.isfinite(learner["policy_loss"])
