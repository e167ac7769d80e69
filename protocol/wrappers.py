"""Wrappers around any :class:`ArenaAPI` (in-process ``Arena`` or remote ``RM``).

A wrapper forwards every call to the arena it wraps and overrides only what it changes, like
Gymnasium's wrappers. :class:`RewardWrapper` is the documented way to add a custom reward:
it sees the per-agent rewards and the referee's ``info`` (reward ``components``, per-robot
``hp``, ``damage_dealt``, ``kills``, ``contacts``, ...) and returns new rewards.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.protocol.interface import ArenaAPI, inherit_docstrings


@inherit_docstrings
class ArenaWrapper(ArenaAPI):
    """Forwards everything to ``env``; subclasses override what they change."""

    def __init__(self, env: ArenaAPI) -> None:
        self.env = env

    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        return self.env.reset(contexts, seed=seed)

    def step(
        self, actions: Sequence[Any]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        return self.env.step(actions)

    def get_obs(self) -> list[np.ndarray]:
        return self.env.get_obs()

    def get_state(self) -> np.ndarray:
        return self.env.get_state()

    def get_avail_actions(self) -> list[np.ndarray]:
        return self.env.get_avail_actions()

    def get_env_info(self) -> dict[str, Any]:
        return self.env.get_env_info()

    def render(self) -> np.ndarray:
        return self.env.render()

    def close(self) -> None:
        self.env.close()


@inherit_docstrings
class RewardWrapper(ArenaWrapper):
    """Replace each step's rewards with :meth:`reward` of the original ones and ``info``."""

    def step(
        self, actions: Sequence[Any]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        obs, rewards, done, info = self.env.step(actions)
        return obs, self.reward(rewards, info), done, info

    def reward(self, rewards: list[float], info: dict[str, Any]) -> list[float]:
        """The new per-agent rewards (override)."""
        raise NotImplementedError


class CollisionPenalty(RewardWrapper):
    """Example custom reward: subtract ``penalty`` for each agent touching anything at the end
    of the decision (a wall, an obstacle or another robot), on top of the arena's reward.

    ``agents`` maps agent order to robot index (``range(n_blue)`` in cooperative mode, all
    robots in competitive mode), since ``info`` lists every robot, blue first.
    """

    def __init__(
        self, env: ArenaAPI, penalty: float = 0.1, agents: Sequence[int] | None = None
    ) -> None:
        super().__init__(env)
        self.penalty = penalty
        self.agents = (
            list(agents) if agents is not None else list(range(env.get_env_info()["n_agents"]))
        )

    def reward(self, rewards: list[float], info: dict[str, Any]) -> list[float]:
        contacts = info["contacts"]
        return [
            r - self.penalty * (contacts[i] > 0) for r, i in zip(rewards, self.agents, strict=True)
        ]
