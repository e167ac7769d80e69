"""``SMACEnv``: the cooperative task behind SMAC's ``MultiAgentEnv`` interface.

PyMARL, EPyMARL's SMAC path, and the many codebases built on SMAC drive an environment
through exactly the methods of SMAC's ``StarCraft2Env``; this class has them, so such code
runs on NeuronsMAE by building ``SMACEnv(**env_args)`` where it built ``StarCraft2Env``::

    env = SMACEnv(seed=0)                      # a private unpaced server; or
    env = SMACEnv(env="neuronsmae.server:Arena", seed=0, action_space="discrete")
    info = env.get_env_info()                  # n_agents, n_actions, state_shape, ...
    env.reset()
    while not terminated:
        actions = [pick(env.get_avail_agent_actions(i)) for i in range(env.n_agents)]
        reward, terminated, info = env.step(actions)

The contract, as SMAC has it:

* ``n_agents``, ``n_enemies``, ``episode_limit`` (decisions) as attributes;
  :meth:`~SMACEnv.get_env_info` gives ``state_shape``, ``obs_shape``, ``n_actions``,
  ``n_agents``, ``episode_limit``.
* ``reset()`` returns ``(obs, state)``; ``get_obs()`` a list of per-agent arrays,
  ``get_state()`` the global state, ``get_avail_actions()`` per-agent lists of 0/1.
* ``step(actions)`` takes one action per agent, anything ``int()`` accepts (Python and numpy
  integers, 0-d or one-element torch tensors), and returns ``(reward, terminated, info)``:
  the team reward (the blue robots share one), whether the episode ended (a wipe-out or the
  time limit), and numeric scalars (:data:`~neuronsmae.client.infos.SCALAR_KEYS`:
  ``battle_won``, ``dead_allies``, ``dead_enemies``, and ``episode_limit``, True when the
  time limit ended it, which PyMARL-style runners read to bootstrap).
* ``get_stats()``: ``battles_won``, ``battles_game``, ``battles_draw``, ``win_rate``,
  ``timeouts``, ``restarts`` since construction.

Actions are discrete (``action_space="abstract"``, the default, or ``"discrete"``) and the
agents are the blue team against the arena's bot, as in SMAC. Arguments are those of the
other faces (:mod:`neuronsmae.client.source`): ``env``, ``seed``, ``contexts``, then
``RM``'s arguments and the arena options.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.client.gym_env import _coop
from neuronsmae.client.infos import start_info, step_info
from neuronsmae.client.source import ArenaSource, FirstSeed, Recipe, open_face
from neuronsmae.client.spaces import Layout, face_contexts, per_agent_actions
from neuronsmae.client.viewer import Renderer
from neuronsmae.protocol.errors import InvalidOptionError


def _smac(layout: Layout) -> None:
    _coop(layout)
    if layout.continuous:
        raise InvalidOptionError(
            "SMACEnv has discrete actions, as SMAC does; valid action_space options: "
            "'abstract', 'discrete'"
        )


class SMACEnv(Recipe):
    """A cooperative arena behind SMAC's ``StarCraft2Env`` methods (see the module
    docstring)."""

    def __init__(
        self,
        env: ArenaSource = None,
        *,
        seed: int | None = None,
        contexts: Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        Recipe.__init__(self, env=env, seed=seed, contexts=contexts, render_mode=render_mode,
                        **kwargs)  # fmt: skip
        self.contexts = face_contexts(contexts)
        self.arena, self.layout, seeded = open_face(env, seed, kwargs, render_mode, "SMACEnv",
                                                    _smac)  # fmt: skip
        self._seed = seed
        self._first_seed = FirstSeed(seeded)
        info = self.layout.info
        self.n_agents = info.n_agents
        """Blue robots (SMAC's allied units)."""
        self.n_enemies = info.n_enemies
        """Red robots."""
        self.episode_limit = info.episode_limit
        """Decisions per episode at most."""
        self.battles_won = self.battles_game = self.battles_draw = self.timeouts = 0
        self.restarts = 0
        """SMAC's episode counters (restarts: always 0, nothing here needs restarting)."""
        self._renderer = Renderer(self.arena.render, render_mode, self.layout.render_fps,
                                  "NeuronsMAE (SMAC)")  # fmt: skip
        self.arena_info: dict[str, Any] = {}
        """The arena's own ``info`` of the last step, unchanged; empty after ``reset``."""
        self.last_info: dict[str, Any] = {}
        """The numeric info of the last ``reset`` or ``step``."""

    # ---- episode ------------------------------------------------------------------------

    def reset(self) -> tuple[list[np.ndarray], np.ndarray]:
        """Start an episode; returns ``(obs, state)``."""
        obs = self.arena.reset(self.contexts or None, self._first_seed(None))
        self.arena_info = {}
        self.last_info = start_info(self.layout.info, self.arena.get_state(), False)
        self._renderer.update()
        return [np.asarray(o, dtype=np.float32) for o in obs], self.get_state()

    def step(self, actions: Sequence[Any]) -> tuple[float, bool, dict[str, Any]]:
        """One decision; returns ``(reward, terminated, info)``."""
        joint = per_agent_actions(actions, self.n_agents)
        _, rewards, done, raw = self.arena.step(joint)
        terminated = bool(done)
        timeout = terminated and not self.layout.annihilated(raw)
        self.arena_info = raw
        info = step_info(self.layout.info, raw, self.arena.get_state(), 0, timeout, False)
        if terminated:
            self.battles_game += 1
            self.battles_won += int(info["battle_won"])
            self.battles_draw += int(raw.get("winner") == "draw")
            self.timeouts += int(timeout)
        self.last_info = info
        self._renderer.update()
        return float(rewards[0]), terminated, info

    # ---- reads --------------------------------------------------------------------------

    def get_obs(self) -> list[np.ndarray]:
        return [np.asarray(o, dtype=np.float32) for o in self.arena.get_obs()]

    def get_obs_agent(self, agent_id: int) -> np.ndarray:
        return self.get_obs()[self._agent(agent_id)]

    def get_obs_size(self) -> int:
        return self.layout.obs_dim

    def get_state(self) -> np.ndarray:
        return np.asarray(self.arena.get_state(), dtype=np.float32)

    def get_state_size(self) -> int:
        return self.layout.state_dim

    def get_avail_actions(self) -> list[list[int]]:
        return [np.asarray(m, dtype=np.int64).tolist() for m in self.arena.get_avail_actions()]

    def get_avail_agent_actions(self, agent_id: int) -> list[int]:
        return self.get_avail_actions()[self._agent(agent_id)]

    def _agent(self, agent_id: Any) -> int:
        """``agent_id`` checked: an integer in [0, n_agents) (an ``IndexError`` otherwise, as
        a list would raise, but naming the range; negative ids are refused, not wrapped)."""
        ok = isinstance(agent_id, (int, np.integer)) and not isinstance(agent_id, bool)
        if not ok or not 0 <= int(agent_id) < self.n_agents:
            raise IndexError(
                f"agent_id must be an integer in [0, {self.n_agents - 1}], got {agent_id!r}"
            )
        return int(agent_id)

    def get_total_actions(self) -> int:
        return self.layout.n_actions

    def get_env_info(self) -> dict[str, Any]:
        """SMAC's five sizes: ``state_shape``, ``obs_shape``, ``n_actions``, ``n_agents``,
        ``episode_limit``."""
        return {
            "state_shape": self.get_state_size(),
            "obs_shape": self.get_obs_size(),
            "n_actions": self.get_total_actions(),
            "n_agents": self.n_agents,
            "episode_limit": self.episode_limit,
        }

    def get_stats(self) -> dict[str, Any]:
        return {
            "battles_won": self.battles_won,
            "battles_game": self.battles_game,
            "battles_draw": self.battles_draw,
            "win_rate": self.battles_won / self.battles_game if self.battles_game else 0.0,
            "timeouts": self.timeouts,
            "restarts": self.restarts,
        }

    # ---- the rest of SMAC's methods -----------------------------------------------------

    def render(self, mode: str = "rgb_array") -> np.ndarray | None:
        """The top-down RGB frame (``mode="rgb_array"``). A window (``mode="human"``) is
        chosen when the environment is built (``render_mode="human"``): it is then updated
        after every step by itself and this returns None."""
        if mode not in ("rgb_array", "human"):
            raise InvalidOptionError(
                f"render mode {mode!r} is not valid; valid: 'rgb_array', 'human'"
            )
        if self._renderer.window is not None:
            return None
        if mode == "human":
            raise InvalidOptionError(
                "render(mode='human') needs a window: build the environment with "
                "render_mode='human' (where there is a display); render() returns frames"
            )
        return np.asarray(self.arena.render(), dtype=np.uint8)

    def close(self) -> None:
        """Close the arena (and the server this environment launched); safe to repeat."""
        self._renderer.close()
        self.arena.close()

    def seed(self) -> int | None:
        """The constructor's seed (SMAC's ``seed()``), None when the first episode was
        seeded from entropy."""
        return self._seed

    def save_replay(self) -> None:
        """SMAC saves a StarCraft II replay here; NeuronsMAE records episodes with
        ``neuronsmae.client.recorder.Recorder`` instead, so this does nothing."""
