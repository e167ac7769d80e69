"""``AgentsEnv``: one Gymnasium environment with a space per agent, in the convention of
EPyMARL's ``gymma``, lbforaging and RWARE.

``gymnasium.make("neuronsmae.client:NeuronsMAE/Agents-v0")`` needs no prior import (the
module before the colon is imported by ``make``), which is what EPyMARL's ``gymma`` wrapper
calls with ``env_args.key``::

    python src/main.py --config=qmix --env-config=gymma with \\
        env_args.key="neuronsmae.client:NeuronsMAE/Agents-v0" env_args.time_limit=50

Conventions (those ``gymma`` relies on):

* ``observation_space`` is a ``Tuple`` of one ``Box(-1, 1, (d,), float32)`` per agent and
  an observation a tuple of arrays; ``action_space`` a ``Tuple`` of one ``Discrete(A)``
  (abstract and discrete actions) or ``Box(4)`` (continuous) per agent, an action any
  sequence of per-agent actions (``int()`` of each is taken for discrete ones).
* ``n_agents`` is the number of agents. ``step`` returns ``(obs, rewards, terminated,
  truncated, info)`` with ``rewards`` a list of per-agent rewards (each robot gets its
  team's reward, so ``gymma``'s ``reward_scalarisation="mean"`` gives the team reward and
  ``"sum"`` n times it), ``terminated`` when a team is wiped out and ``truncated`` at the
  time limit with both teams standing.
* ``info`` holds scalars only (:data:`~neuronsmae.client.infos.SCALAR_KEYS`: ``battle_won``,
  ``episode_limit``, ``dead_allies``, ``dead_enemies``, ...), the same keys after ``reset``
  as after ``step``: EPyMARL sums every value of an episode's last info and logs the means,
  and reads ``episode_limit`` to tell the time limit from a real end.
* Masks cannot travel in this convention (``gymma`` allows every action); a masked action
  is accepted by the arena anyway (a dead robot's or a missing target's is replaced), and
  :meth:`AgentsEnv.get_avail_actions` gives them to code that asks.
* There is deliberately no ``state_size`` attribute: ``gymma`` would then take it for the
  size of its own state, the concatenated observations. :meth:`AgentsEnv.state` gives the
  arena's global state to code that wants it.

Pick the arena with ``env`` (:mod:`neuronsmae.client.source`): by default a private unpaced
server per environment; ``env="neuronsmae.server:Arena"`` runs it in the process. EPyMARL
passes no arguments but the key (its configuration refuses keys it does not know), so the
usual choices have ids of their own (:func:`~neuronsmae.client.gym_env.agents_ids`):
``NeuronsMAE/Agents-InProcess-v0`` for an arena in the process, ``NeuronsMAE/Agents-hard-v0``
(``-easy-``, ``-middle-``) for another bot, ``NeuronsMAE/Agents-InProcess-hard-v0`` both.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

from neuronsmae.client.gym_env import AGENTS_ENV_ID, EpisodeSpec
from neuronsmae.client.infos import start_info, step_info
from neuronsmae.client.source import ArenaSource, FirstSeed, Recipe, open_face
from neuronsmae.client.spaces import face_contexts, per_agent_actions, reset_contexts
from neuronsmae.client.viewer import HUMAN, RGB_ARRAY, Renderer, render_modes
from neuronsmae.protocol.interface import seed_value


class AgentsEnv(EpisodeSpec, Recipe, gymnasium.Env[tuple[np.ndarray, ...], Sequence[Any]]):
    """Every agent of an arena (the blue robots; blue then red in ``mode="competitive"``),
    each with its own space in a ``Tuple``.

    Arguments as for :class:`~neuronsmae.client.gym_env.CoopEnv`: ``env``, ``seed``,
    ``render_mode``, ``contexts``, then ``RM``'s arguments and the arena options.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": [HUMAN, RGB_ARRAY], "render_fps": 2.5}

    def __init__(
        self,
        env: ArenaSource = None,
        *,
        seed: int | None = None,
        render_mode: str | None = None,
        contexts: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> None:
        Recipe.__init__(self, env=env, seed=seed, render_mode=render_mode, contexts=contexts,
                        **kwargs)  # fmt: skip
        self.render_mode = render_mode
        self.contexts = face_contexts(contexts)
        self.arena, self.layout, seeded = open_face(env, seed, kwargs, render_mode, "AgentsEnv")
        layout = self.layout
        self._first_seed = FirstSeed(seeded)
        self.n_agents = n = len(layout.agents)
        """Agents, the entries of an observation, an action and the rewards."""
        self.agents = layout.agents
        """Their names, in order (``blue_0``, ...)."""
        self.metadata = {
            **type(self).metadata,
            "render_modes": render_modes(),
            "render_fps": layout.render_fps,
        }
        self.observation_space = spaces.Tuple([layout.obs_space() for _ in range(n)])
        self.action_space = spaces.Tuple([layout.agent_action_space() for _ in range(n)])
        self._teams = [layout.team_of(i) for i in range(n)]
        self._renderer = Renderer(self.arena.render, render_mode, layout.render_fps, AGENTS_ENV_ID)
        self.arena_info: dict[str, Any] = {}
        """The arena's own ``info`` of the last step, unchanged; empty after ``reset``."""

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[tuple[np.ndarray, ...], dict[str, Any]]:
        """Start an episode; ``seed`` re-seeds the arena; ``options={"contexts": ...}`` as
        ``CoopEnv``'s."""
        seed = None if seed is None else seed_value(seed)  # the arena's error, not Gymnasium's
        super().reset(seed=seed)
        contexts = reset_contexts(self.contexts, options)
        obs = self.arena.reset(contexts or None, self._first_seed(seed))
        self.arena_info = {}
        self._renderer.update()
        return self._tuple(obs), start_info(self.layout.info, self.arena.get_state(), False)

    def step(
        self, actions: Sequence[Any]
    ) -> tuple[tuple[np.ndarray, ...], list[float], bool, bool, dict[str, Any]]:
        rows = per_agent_actions(actions, self.n_agents, not self.layout.continuous)
        joint = [self.layout.to_arena(name, a) for name, a in zip(self.agents, rows, strict=True)]
        obs, rewards, done, raw = self.arena.step(joint)
        terminated = bool(done) and self.layout.annihilated(raw)
        truncated = bool(done) and not terminated
        self.arena_info = raw
        info = step_info(self.layout.info, raw, self.arena.get_state(), self._teams[0],
                         truncated, False)  # fmt: skip
        self._renderer.update()
        return self._tuple(obs), [float(r) for r in rewards], terminated, truncated, info

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """The top-down RGB frame (H × W × 3 uint8) when ``render_mode="rgb_array"``."""
        return self._renderer.render()

    def close(self) -> None:
        """Close the arena (and the server this environment launched); safe to repeat."""
        self._renderer.close()
        self.arena.close()

    # ---- beyond the convention ----------------------------------------------------------

    def get_avail_actions(self) -> list[np.ndarray]:
        """Each agent's mask (int8, 1 = allowed; see ``ArenaAPI.get_avail_actions``)."""
        return [np.asarray(m, dtype=np.int8) for m in self.arena.get_avail_actions()]

    def state(self) -> np.ndarray:
        """The arena's global state (every robot's pose, HP, bullets; the time)."""
        return np.asarray(self.arena.get_state(), dtype=np.float32)

    def _tuple(self, obs: list[np.ndarray]) -> tuple[np.ndarray, ...]:
        return tuple(np.asarray(o, dtype=np.float32) for o in obs)
