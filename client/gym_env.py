"""``CoopEnv``: the cooperative task as one Gymnasium environment under centralised control.

One policy observes every blue robot and commands all of them at once, so the team is a
single Gymnasium agent and any single-agent library (Stable-Baselines3, CleanRL, ...) can
train it. The red team is the arena's bot. For one learner per robot, use the PettingZoo
face (:mod:`neuronsmae.client.pz_env`), the per-agent Gymnasium face of EPyMARL's ``gymma``
(:mod:`neuronsmae.client.agents_env`) or the SMAC adapter (:mod:`neuronsmae.client.smac`).

``gymnasium.make("NeuronsMAE/Coop-v0")`` (after ``import neuronsmae.client``; without it,
the id ``"neuronsmae.client:NeuronsMAE/Coop-v0"``) launches a private, unpaced server on a
free loopback port and stops it on ``close()``, so any number run side by side;
``gymnasium.make_vec("NeuronsMAE/Coop-v0", num_envs=N)`` puts N arenas on one vector server
(:mod:`neuronsmae.client.vec_env`). See :mod:`neuronsmae.client.source` for ``env=``, the
other keyword arguments and seeding.

Spaces (``n`` blue robots, observation length ``d``; see :mod:`neuronsmae.client.spaces`):

* observation: ``Box(-1, 1, (n, d), float32)``, agent ``i``'s vector in row ``i``. Stacked
  rather than concatenated so row ``i`` lines up with action ``i`` and with mask row ``i``;
  ``gymnasium.wrappers.FlattenObservation`` gives the concatenation when a library wants it.
* action: ``MultiDiscrete([n_actions] * n)`` for abstract and discrete actions;
  ``Box((n, 4), float32)`` of rows ``(vx, vy, omega, target)`` for continuous actions, the
  target read as a bin (enemy ``i`` is ``[i, i + 1)``).
* reward: the blue team's reward. The arena gives every blue robot the same team reward,
  so this is any one of them (the first), not their sum, and keeps the arena's scale.
* ``terminated`` when a team is wiped out, ``truncated`` at the time limit with both teams
  standing. The arena keeps time itself; ``spec.max_episode_steps`` (from ``make``) is its
  ``episode_limit`` in decisions, so a ``TimeLimit`` added on top never cuts earlier.
* info, after ``reset`` and every ``step`` alike: numbers and arrays only
  (:mod:`neuronsmae.client.infos`: ``t``, ``battle_won``, ``episode_limit``,
  ``dead_allies``, ``hp_fraction``, ...) plus the masks, ``info["action_mask"]``
  ((n, n_actions) int8: pass ``tuple(mask)`` to ``action_space.sample``) or, for continuous
  actions, ``info["target_mask"]`` ((n, n_enemies)). :meth:`CoopEnv.action_masks` gives
  sb3-contrib's flat boolean form; :attr:`CoopEnv.arena_info` the arena's own last info.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec

from neuronsmae.client.infos import start_info, step_info
from neuronsmae.client.source import ArenaSource, FirstSeed, Recipe, open_face
from neuronsmae.client.spaces import Layout, face_contexts, reset_contexts
from neuronsmae.client.viewer import HUMAN, RGB_ARRAY, Renderer, render_modes
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError
from neuronsmae.protocol.interface import seed_value

ENV_ID = "NeuronsMAE/Coop-v0"
AGENTS_ENV_ID = "NeuronsMAE/Agents-v0"
"""The per-agent face (:class:`~neuronsmae.client.agents_env.AgentsEnv`)."""
PAPER_LEVELS = ("easy", "middle", "hard")
"""The paper's bots, each with an id of the per-agent face (:func:`agents_ids`)."""
IN_PROCESS = "neuronsmae.server:Arena"
"""``env=`` for an arena built in this process."""


def agents_ids() -> dict[str, dict[str, Any]]:
    """The per-agent face's ids and the arguments each one stands for.

    A configuration file may only be able to name an environment, not pass it arguments
    (EPyMARL's ``gymma`` takes ``env_args.key`` and refuses keys it does not know), so the
    usual choices have ids of their own, in the manner of lbforaging's
    ``Foraging-8x8-2p-3f-v3``: ``NeuronsMAE/Agents[-InProcess][-<level>]-v0`` with ``level``
    one of :data:`PAPER_LEVELS` (red's bot; the default is easy) and ``InProcess`` for an
    arena in the calling process instead of a private server. For anything else, register
    an id with ``gymnasium.register(id, entry_point="neuronsmae.client.agents_env:AgentsEnv",
    kwargs={...})`` in a module of your own and name it ``"yourmodule:YourId"``.
    """
    ids: dict[str, dict[str, Any]] = {}
    for place, env in (("", None), ("InProcess-", IN_PROCESS)):
        for level in (None, *PAPER_LEVELS):
            kwargs: dict[str, Any] = {} if env is None else {"env": env}
            if level is not None:
                kwargs["contexts"] = {"level": level}
            ids[f"NeuronsMAE/Agents-{place}{'' if level is None else level + '-'}v0"] = kwargs
    return ids


def _coop(layout: Layout) -> None:
    if layout.mode != "cooperative":
        raise InvalidOptionError(
            f"CoopEnv drives one team, so it needs mode='cooperative', got "
            f"{layout.mode!r}; use the PettingZoo face for both teams"
        )


class EpisodeSpec:
    """``spec`` as Gymnasium's ``make`` sets it, with ``max_episode_steps`` filled in from
    the arena's ``episode_limit`` (a class attribute shared by the faces)."""

    _spec: EnvSpec | None = None
    layout: Layout

    @property
    def spec(self) -> EnvSpec | None:
        """The registration ``make`` used (None when built directly), its
        ``max_episode_steps`` the arena's ``episode_limit`` in decisions."""
        spec = self._spec
        if spec is None or spec.max_episode_steps is not None:
            return spec
        return dataclasses.replace(spec, max_episode_steps=self.layout.episode_limit)

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        self._spec = value


class CoopEnv(EpisodeSpec, Recipe, gymnasium.Env[np.ndarray, np.ndarray]):
    """All blue robots of a cooperative arena as one Gymnasium environment.

    ``CoopEnv()`` launches a private unpaced server; ``CoopEnv(seed=0, action_space=
    "discrete", ...)`` configures its arena; ``CoopEnv(env="neuronsmae.server:Arena", ...)``
    builds the arena in this process; ``CoopEnv(env=Arena(...))`` or ``env=lambda:
    Arena(...)`` wraps the caller's (see :mod:`neuronsmae.client.source`). The environment
    owns its arena whichever way it came — :meth:`close` closes it — except when
    construction fails: an arena passed in is then left to the caller.

    ``contexts`` are the reset contexts of every episode; ``reset(options={"contexts": ...})``
    updates them for one episode (keys given there win; other option keys are ignored).
    ``render_mode`` is ``"rgb_array"``, ``"human"`` (a window; :mod:`neuronsmae.client.viewer`)
    or None.
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
        self.arena, self.layout, seeded = open_face(
            env, seed, kwargs, render_mode, "CoopEnv", _coop
        )
        layout = self.layout
        self._first_seed = FirstSeed(seeded)
        self.n_agents = n = len(layout.agents)
        """Blue robots, the rows of an observation and of an action."""
        self.metadata = {
            **type(self).metadata,
            "render_modes": render_modes(),
            "render_fps": layout.render_fps,
        }
        self.observation_space = layout.obs_space(n)
        self.action_space: spaces.Space[np.ndarray] = (
            layout.motion_box(n) if layout.continuous
            else spaces.MultiDiscrete(np.full(n, layout.n_actions, dtype=np.int64))
        )  # fmt: skip
        self._masks = np.zeros((n, layout.n_actions), dtype=np.int8)
        self._renderer = Renderer(self.arena.render, render_mode, layout.render_fps, ENV_ID)
        self.arena_info: dict[str, Any] = {}
        """The arena's own ``info`` of the last step, unchanged (``winner``, ``components``,
        ``targets``, ...; see ``ArenaAPI.step``); empty after ``reset``."""

    # ---- Gymnasium API ------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` re-seeds the arena, as ``ArenaAPI.reset`` does."""
        seed = None if seed is None else seed_value(seed)  # the arena's error, not Gymnasium's
        super().reset(seed=seed)
        contexts = reset_contexts(self.contexts, options)
        obs = self.arena.reset(contexts or None, self._first_seed(seed))
        self.arena_info = {}
        info = start_info(self.layout.info, self.arena.get_state())
        self._renderer.update()
        return self._stack(obs), {**info, **self._mask_info()}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, rewards, done, raw = self.arena.step(self._to_arena(action))
        terminated = bool(done) and self.layout.annihilated(raw)
        truncated = bool(done) and not terminated
        self.arena_info = raw
        info = step_info(self.layout.info, raw, self.arena.get_state(), 0, truncated)
        self._renderer.update()
        return self._stack(obs), float(rewards[0]), terminated, truncated, {
            **info, **self._mask_info()
        }  # fmt: skip

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """The top-down RGB frame (H × W × 3 uint8) when ``render_mode="rgb_array"``."""
        return self._renderer.render()

    def close(self) -> None:
        """Close the arena (and the server this environment launched); safe to repeat."""
        self._renderer.close()
        self.arena.close()

    # ---- beyond Gymnasium ---------------------------------------------------------------

    def state(self) -> np.ndarray:
        """The arena's global state (every robot's pose, HP, bullets; the time)."""
        return np.asarray(self.arena.get_state(), dtype=np.float32)

    def action_masks(self) -> np.ndarray:
        """The current masks flattened to booleans, agent after agent: what sb3-contrib's
        ``MaskablePPO`` expects from a ``MultiDiscrete`` environment."""
        return self._masks.astype(bool).reshape(-1)

    # ---- helpers ------------------------------------------------------------------------

    def _stack(self, obs: list[np.ndarray]) -> np.ndarray:
        return np.stack([np.asarray(o, dtype=np.float32) for o in obs])

    def _mask_info(self) -> dict[str, np.ndarray]:
        self._masks = np.stack(
            [np.asarray(m, dtype=np.int8) for m in self.arena.get_avail_actions()]
        )
        return {self.layout.mask_key: self._masks.copy()}

    def _to_arena(self, action: Any) -> list[Any]:
        """Rows of the joint action → the arena's per-agent actions."""
        joint = np.asarray(action)
        want = self.action_space.shape
        if joint.shape != want:
            raise InvalidActionError(
                f"the joint action must have shape {want} (one entry per blue robot), got "
                f"shape {joint.shape}"
            )
        return [
            self.layout.to_arena(name, row)
            for name, row in zip(self.layout.agents, joint, strict=True)
        ]


def register_envs() -> None:
    """Register NeuronsMAE's Gymnasium ids (idempotent).

    * ``NeuronsMAE/Coop-v0``: :class:`CoopEnv`; its ``vector_entry_point`` is
      :class:`~neuronsmae.client.vec_env.CoopVectorEnv`, so ``gymnasium.make_vec`` builds one
      vector server of N arenas (``vectorization_mode="sync"`` gives N environments with a
      server each, ``"async"`` the same in subprocesses: pass
      ``vector_kwargs={"context": "spawn"}``, since Zenoh does not survive ``fork``).
    * ``NeuronsMAE/Agents-v0``: :class:`~neuronsmae.client.agents_env.AgentsEnv`, per-agent
      ``Tuple`` spaces in the convention of EPyMARL's ``gymma`` (registered without
      Gymnasium's single-agent checker, whose warnings its reward list would trigger), and
      its variants for the paper's bots and in-process arenas (:func:`agents_ids`).

    Entry points are strings, so registering imports no face and starts nothing. Without
    importing ``neuronsmae.client`` first, use the ids prefixed with ``"neuronsmae.client:"``.
    """
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(
            id=ENV_ID,
            entry_point="neuronsmae.client.gym_env:CoopEnv",
            vector_entry_point="neuronsmae.client.vec_env:CoopVectorEnv",
        )
    for env_id, kwargs in agents_ids().items():
        if env_id not in gymnasium.registry:
            gymnasium.register(
                id=env_id,
                entry_point="neuronsmae.client.agents_env:AgentsEnv",
                disable_env_checker=True,
                kwargs=kwargs,
            )
