"""Reward wrappers see the referee's info and change only the rewards."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.protocol.wrappers import CollisionPenalty, RewardWrapper
from neuronsmae.server import Arena


def test_collision_penalty_applies_to_touching_agents_only() -> None:
    arena = Arena(seed=1, action_space="continuous", mode="competitive")
    env = CollisionPenalty(arena, penalty=0.5)
    env.reset()
    # blue_0 drives into the left wall; blue_1 stands free; nobody can shoot.
    arena.place(
        np.array([(0.6, 1.9, np.pi), (2.5, 3.9, 0.0), (7.4, 3.9, np.pi), (7.5, 0.6, np.pi)]),
        bullets=[0, 0, 0, 0],
    )
    still = np.zeros(4)
    _, rewards, _, info = env.step([np.array([2.0, 0, 0, 0]), still, still, still])
    assert info["contacts"][0] > 0 and info["contacts"][1] == 0
    assert rewards[0] == pytest.approx(-0.5) and rewards[1] == 0.0
    env.close()


def test_reward_wrapper_must_define_reward() -> None:
    env = RewardWrapper(Arena(seed=1))
    env.reset()
    with pytest.raises(NotImplementedError):
        env.step([0, 0])
    env.close()
