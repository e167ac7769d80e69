"""The one environment interface, implemented by the in-process ``Arena`` and the remote ``RM``.

Both ``neuronsmae.server.Arena`` and ``neuronsmae.client.RM`` subclass :class:`ArenaAPI`, so
they have exactly the same methods, signatures, return values and docstrings. Training code
written against one runs unchanged against the other. The vocabulary follows the released
NeuronsMAE wrappers (``reset(contexts)``) and SMAC (``get_obs``, ``get_state``,
``get_avail_actions``, ``get_env_info``).

Agents are the robots the caller controls, in a fixed order: in cooperative mode the blue
team (indices ``0 .. n_blue-1``); in competitive mode blue then red. Lists returned by the
methods below are indexed by that order.
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

Action = Any
"""One agent's action: an ``int`` (abstract, discrete) or 4 floats ``(vx, vy, omega, target)``."""


class ArenaAPI(abc.ABC):
    """The environment contract shared by in-process and remote arenas."""

    @abc.abstractmethod
    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        """Start a new episode and return each agent's first observation.

        ``contexts`` sets the dynamics, referee and opponent parameters for this episode
        (keys such as ``Friction_coeff``, ``VK1``, ``coef``, ``level``; see
        ``docs/contexts.md``). Keys left out take their defaults, not the previous episode's
        values, so an episode is fully described by its seed and contexts. ``seed`` re-seeds
        the arena's own RNG; without it the RNG continues from the previous episode, so a
        freshly built arena with seed ``s`` always produces the same sequence of episodes.

        Raises ``InvalidContextError`` (a ``ValueError``) naming the key and what is valid.
        """

    @abc.abstractmethod
    def step(
        self, actions: Sequence[Action]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        """Apply one decision for every agent and advance one decision period.

        Returns ``(obs, rewards, done, info)``: per-agent observations, per-agent rewards
        summed over the decision period, whether the episode ended, and the referee's
        ``info`` (per-robot ``hp``, ``bullets``, ``damage_dealt``, ``kills``, ``alive``;
        ``winner`` in {"blue", "red", "draw", None}; the reward ``components``; ``t``).

        Raises ``InvalidActionError`` (a ``ValueError``) naming the agent and the bound,
        and ``ResetNeededError`` before the first reset or after the episode ended.
        """

    @abc.abstractmethod
    def get_obs(self) -> list[np.ndarray]:
        """Each agent's current observation (the same arrays ``step`` last returned)."""

    @abc.abstractmethod
    def get_state(self) -> np.ndarray:
        """The true global state for centralised training, from a fixed (blue-first) view.

        Every robot's pose, HP and bullets and the time, normalised to [-1, 1]. It never
        depends on observability options: it is not one agent's observation.
        """

    @abc.abstractmethod
    def get_avail_actions(self) -> list[np.ndarray]:
        """Per-agent masks (``int8``, 1 = allowed) over the discrete action choices.

        For abstract and discrete actions the mask covers the ``n_actions`` flat indices; for
        continuous actions it covers the target enemy. A destroyed robot may only take its
        no-op (index 0).
        """

    @abc.abstractmethod
    def get_env_info(self) -> dict[str, Any]:
        """Shapes and sizes: ``n_actions``, ``n_agents``, ``state_shape``, ``obs_shape``,
        ``episode_limit`` (decisions per episode), plus ``action_space``, ``agents``,
        ``n_enemies``, ``decision_steps``, ``mode`` and what fixes the observation's layout
        (``team_size``, ``k``, ``candidate_obs``, ``vector_obs``, ``lidar_beams``).
        :meth:`EnvInfo.from_dict <neuronsmae.protocol.env_info.EnvInfo.from_dict>` parses
        it into a typed object that names every column."""

    @abc.abstractmethod
    def render(self) -> np.ndarray:
        """A top-down RGB image (``uint8``, H × W × 3) of the current scene."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the arena's resources; safe to call more than once."""

    def __enter__(self) -> ArenaAPI:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def inherit_docstrings(cls: type) -> type:
    """Class decorator: each method overriding an :class:`ArenaAPI` method without a
    docstring of its own gets the interface's, so ``help(RM.step)``, ``help(Arena.step)``
    and a wrapper's ``step`` all tell the same contract."""
    for name in ArenaAPI.__abstractmethods__:
        method = cls.__dict__.get(name)
        if method is not None and not method.__doc__:
            method.__doc__ = getattr(ArenaAPI, name).__doc__
    return cls
