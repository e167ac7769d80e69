"""``CoopEnv``: the cooperative task as one Gymnasium environment under centralised control.

One policy observes every blue robot and commands all of them at once, so the team is a
single Gymnasium agent and any single-agent library (Stable-Baselines3, CleanRL, ...) can
train it. The red team is the arena's bot. For one learner per robot, or for both teams,
use the PettingZoo face (:mod:`neuronsmae.client.pz_env`).

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
  standing. There is no ``TimeLimit`` wrapper: the arena keeps time itself.
* info: the arena's ``info`` (``hp``, ``alive``, ``winner``, ``t``, ...) plus the masks,
  ``info["action_mask"]`` ((n, n_actions) int8: pass ``tuple(mask)`` to
  ``action_space.sample``) or, for continuous actions, ``info["target_mask"]``
  ((n, n_enemies)). :meth:`CoopEnv.action_masks` gives sb3-contrib's flat boolean form.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces

from neuronsmae.client.spaces import ArenaSource, Layout, open_face
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError

ENV_ID = "NeuronsMAE/Coop-v0"
RENDER_MODES = ("rgb_array",)


def _coop(layout: Layout) -> None:
    if layout.mode != "cooperative":
        raise InvalidOptionError(
            f"CoopEnv drives one team, so it needs mode='cooperative', got "
            f"{layout.mode!r}; use the PettingZoo face for both teams"
        )


class CoopEnv(gymnasium.Env[np.ndarray, np.ndarray]):
    """All blue robots of a cooperative arena as one Gymnasium environment.

    ``CoopEnv(env=Arena(seed=0, action_space="discrete"))`` wraps an in-process arena;
    ``CoopEnv(env=lambda: Arena(...))`` builds one from a factory, which is what
    ``gymnasium.make`` needs when it re-creates the environment (``check_env``, vector envs);
    ``CoopEnv(seed=0, port=10000, action_space="discrete", ...)`` (no ``env``) builds a remote
    ``RM`` with those arguments, launching a local server if none answers. The environment
    owns its arena whichever way it came — :meth:`close` closes it — except when construction
    fails: an arena passed in is then left to the caller.

    ``contexts`` are the reset contexts of every episode; ``reset(options={"contexts": ...})``
    updates them for one episode (keys given there win; other option keys are ignored).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": list(RENDER_MODES), "render_fps": 2.5}

    def __init__(
        self,
        env: ArenaSource = None,
        *,
        render_mode: str | None = None,
        contexts: Mapping[str, Any] | None = None,
        **rm_kwargs: Any,
    ) -> None:
        self.render_mode = render_mode
        self.contexts = dict(contexts or {})
        self.arena, self.layout = open_face(env, rm_kwargs, render_mode, RENDER_MODES, _coop)
        layout = self.layout
        self.n_agents = n = len(layout.agents)
        self.metadata = {**type(self).metadata, "render_fps": layout.render_fps}
        self.observation_space = layout.obs_space(n)
        self.action_space: spaces.Space[np.ndarray] = (
            layout.motion_box(n) if layout.continuous
            else spaces.MultiDiscrete(np.full(n, layout.n_actions, dtype=np.int64))
        )  # fmt: skip
        self._masks = np.zeros((n, layout.n_actions), dtype=np.int8)

    # ---- Gymnasium API ------------------------------------------------------------------

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; ``seed`` re-seeds the arena, as ``ArenaAPI.reset`` does."""
        super().reset(seed=seed)
        contexts = {**self.contexts, **dict((options or {}).get("contexts") or {})}
        obs = self.arena.reset(contexts or None, seed)
        return self._stack(obs), self._mask_info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        obs, rewards, done, info = self.arena.step(self._to_arena(action))
        terminated = bool(done) and self.layout.annihilated(info)
        truncated = bool(done) and not terminated
        info = {**info, **self._mask_info()}
        return self._stack(obs), float(rewards[0]), terminated, truncated, info

    def render(self) -> np.ndarray | None:  # type: ignore[override]
        """The top-down RGB frame (H × W × 3 uint8) when ``render_mode="rgb_array"``."""
        if self.render_mode is None:
            gymnasium.logger.warn(
                "render() was called without a render_mode; build with render_mode='rgb_array'"
            )
            return None
        return np.asarray(self.arena.render(), dtype=np.uint8)

    def close(self) -> None:
        """Close the arena (and the server this environment launched); safe to repeat."""
        self.arena.close()

    # ---- masks --------------------------------------------------------------------------

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
    """Register ``NeuronsMAE/Coop-v0`` with Gymnasium (idempotent).

    The entry point is a string, so registering imports neither this module's dependencies
    nor a server; ``gymnasium.make("NeuronsMAE/Coop-v0", env=lambda: Arena(...))`` wraps an
    in-process arena and ``gymnasium.make("NeuronsMAE/Coop-v0", seed=0, port=...)`` a remote
    one. Without importing ``neuronsmae.client`` first, use the id
    ``"neuronsmae.client:NeuronsMAE/Coop-v0"``.
    """
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="neuronsmae.client.gym_env:CoopEnv")
