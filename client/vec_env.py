"""``CoopVectorEnv``: N copies of :class:`~neuronsmae.client.gym_env.CoopEnv` as one
Gymnasium ``VectorEnv``, stepped together by one vector server.

``gymnasium.make_vec("NeuronsMAE/Coop-v0", num_envs=N)`` builds this (the id's
``vector_entry_point``): one private, unpaced ``neuronsmae-server --arenas N`` behind a
:class:`~neuronsmae.client.vec_rm.VecRM`, so a step of all N arenas is one request. With
``env="neuronsmae.server:VecArena"`` the N arenas run in this process instead; ``env=`` may
also be a ``VecArenaAPI`` object or a factory of one (:mod:`neuronsmae.client.source`).

Environment ``i`` is ``CoopEnv`` with seed ``seed + i``, exactly: given the same actions,
``reset(seed=s)`` here and ``reset(seed=s + i)`` on a ``CoopEnv`` of the same options give
the same observations, rewards, terminations, truncations and infos, through autoresets.

* Spaces are ``CoopEnv``'s batched: observations ``[N, n, d]`` float32, actions ``[N, n]``
  (``[N, n, 4]`` continuous), rewards ``[N]`` (the blue team's), ``terminated`` and
  ``truncated`` ``[N]``.
* Autoreset is Gymnasium's next-step mode (``metadata["autoreset_mode"]`` is
  ``AutoresetMode.NEXT_STEP``), the servers' own: an environment that ends at step ``t``
  is reset by step ``t + 1``, which ignores its action and returns its first observation,
  reward 0, neither terminated nor truncated, and its reset info. The reset continues the
  arena's RNG and reuses the contexts of the last :meth:`CoopVectorEnv.reset`.
* Infos follow Gymnasium's vector convention: each key of ``CoopEnv``'s info
  (:mod:`neuronsmae.client.infos` and the masks) holds one row per environment, and
  ``info["_" + key]`` says which environments have it (all of them, always).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from neuronsmae.client.gym_env import ENV_ID, EpisodeSpec, _coop
from neuronsmae.client.infos import start_info, step_info
from neuronsmae.client.source import FirstSeed, Recipe, open_vec_arena
from neuronsmae.client.spaces import Layout, face_contexts, reset_contexts
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError
from neuronsmae.protocol.interface import VecArenaAPI


class CoopVectorEnv(EpisodeSpec, Recipe, VectorEnv[np.ndarray, np.ndarray, np.ndarray]):
    """``num_envs`` cooperative arenas as one Gymnasium vector environment.

    Arguments are :class:`~neuronsmae.client.gym_env.CoopEnv`'s (``seed``, ``contexts``,
    ``env``, ``RM``'s and the arena options) plus ``num_envs``, and ``servers`` to spread the
    arenas over several private vector servers (one by default). ``render_mode`` must be
    None: vector servers do not render (render one ``CoopEnv`` instead).

    Like the one-arena faces it pickles (and ``copy.deepcopy``-s) as its recipe: the copy is
    built anew from the same arguments, launching vector servers of its own when served; one
    wrapping a ``VecArenaAPI`` object raises
    :class:`~neuronsmae.protocol.errors.NotCopyableError` (a ``TypeError``).
    """

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": [],
    }

    def __init__(
        self,
        num_envs: int = 1,
        env: Any = None,
        *,
        seed: int | None = None,
        contexts: Mapping[str, Any] | None = None,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        Recipe.__init__(self, num_envs=num_envs, env=env, seed=seed, contexts=contexts,
                        render_mode=render_mode, **kwargs)  # fmt: skip
        if render_mode is not None:
            raise InvalidOptionError(
                f"render_mode={render_mode!r}: a vector of served arenas does not render; "
                "use render_mode=None, or render one gymnasium.make(...) environment"
            )
        self.render_mode = None
        self.contexts = face_contexts(contexts)
        self.vec, seeded = open_vec_arena(env, seed, num_envs, kwargs, "CoopVectorEnv")
        try:
            self.layout = layout = Layout.of(self.vec)
            _coop(layout)
        except BaseException:
            if not isinstance(env, VecArenaAPI):
                self.vec.close()
            raise
        self.num_envs = num_envs
        self._first_seed = FirstSeed(seeded, span=num_envs)
        n = len(layout.agents)
        self.n_agents = n
        self.metadata = {**type(self).metadata, "render_fps": layout.render_fps}
        self.single_observation_space = layout.obs_space(n)
        self.single_action_space: spaces.Space[np.ndarray] = (
            layout.motion_box(n) if layout.continuous
            else spaces.MultiDiscrete(np.full(n, layout.n_actions, dtype=np.int64))
        )  # fmt: skip
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._ended = np.zeros(num_envs, dtype=bool)
        self.arena_infos: list[dict[str, Any]] = [{} for _ in range(num_envs)]
        """Each arena's own ``info`` of the last step (empty where it was reset)."""

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Reset every environment: ``seed`` an int (environment ``i`` gets ``seed + i``) or
        one per environment; ``options={"contexts": {...}}`` as ``CoopEnv``'s, for all."""
        if isinstance(options, Mapping) and "reset_mask" in options:
            raise InvalidOptionError(
                "options['reset_mask']: the arenas reset together (or by autoreset); valid "
                "options: ['contexts']"
            )
        contexts = reset_contexts(self.contexts, options)
        obs = self.vec.reset(contexts or None, self._first_seed(seed))  # checks the seed
        if isinstance(seed, (int, np.integer)):
            self._np_random, self._np_random_seed = np.random.default_rng(int(seed)), int(seed)
        self._ended[:] = False
        self.arena_infos = [{} for _ in range(self.num_envs)]
        state = self.vec.get_state()
        infos = [start_info(self.layout.info, state[i]) for i in range(self.num_envs)]
        return obs, self._vector_info(infos)

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        joint = np.asarray(actions)
        want = self.action_space.shape
        if joint.shape != want:
            raise InvalidActionError(
                f"actions must have shape {want} (a row per environment, an entry per blue "
                f"robot), got shape {joint.shape}"
            )
        obs, rewards, dones, raws = self.vec.step(self.layout.joint_to_arena(joint))
        state = self.vec.get_state()
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        infos = []
        for i in range(self.num_envs):
            if self._ended[i]:  # autoreset by this step: its reset info
                self.arena_infos[i] = {}
                infos.append(start_info(self.layout.info, state[i]))
                continue
            done = bool(dones[i])
            terminated[i] = done and self.layout.annihilated(raws[i])
            truncated[i] = done and not terminated[i]
            self.arena_infos[i] = raws[i]
            infos.append(step_info(self.layout.info, raws[i], state[i], 0, truncated[i]))
        self._ended = terminated | truncated
        reward = np.asarray(rewards, dtype=np.float64)[:, 0].copy()
        return obs, reward, terminated, truncated, self._vector_info(infos)

    def close_extras(self, **kwargs: Any) -> None:
        """Close the arenas (and the servers this environment launched); nothing when
        construction failed before they were opened."""
        vec = getattr(self, "vec", None)
        if vec is not None:
            vec.close()

    def state(self) -> np.ndarray:
        """``[N, S]``: every arena's global state."""
        return np.asarray(self.vec.get_state(), dtype=np.float32)

    def _vector_info(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        masks = np.asarray(self.vec.get_avail_actions(), dtype=np.int8)
        out: dict[str, Any] = {}
        for i, info in enumerate(infos):
            out = self._add_info(out, {**info, self.layout.mask_key: masks[i]}, i)
        return out

    def __repr__(self) -> str:
        return f"CoopVectorEnv({ENV_ID}, num_envs={self.num_envs})"
