"""``ArenaParallelEnv``: the arena as a PettingZoo ``ParallelEnv``, one agent per robot.

For decentralised learners (independent or parameter-shared policies, MAPPO with
:meth:`~ArenaParallelEnv.state`) and for self-play: in ``mode="cooperative"`` the agents are
the blue robots against the arena's bot, in ``mode="competitive"`` blue then red robots.

PettingZoo semantics, as chosen here (see :mod:`neuronsmae.client.spaces` for the spaces):

* Observations are ``Dict({"observation": Box(-1, 1, (d,), float32), <mask>})``, the
  convention of PettingZoo's classic environments that its tests and the usual trainers
  read. ``<mask>`` is ``"action_mask"`` (``Box(0, 1, (n_actions,), int8)``) for abstract and
  discrete actions and ``"target_mask"`` (``(n_enemies,)``) for continuous ones, whose
  ``Box(4)`` action cannot be sampled with a mask. Masks live only there, never in infos.
* A destroyed robot is *terminated* in the step it is destroyed (it gets that step's
  observation, reward and info) and leaves :attr:`agents`; it never comes back. The arena
  still needs an action for it, so the environment sends its no-op. When a team is wiped out
  every remaining agent is terminated; at the time limit with both teams standing every
  remaining agent is truncated. Either way :attr:`agents` is then empty.
* Rewards are per agent: each robot gets its team's reward, as the arena reports it.
* Actions are needed for every agent in :attr:`agents`; actions for other names are ignored.
* Infos are the arena's ``info`` (``hp``, ``alive``, ``winner``, ``t``, ...), one copy per
  agent; ``reset`` gives empty infos.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces
from pettingzoo.utils.env import ParallelEnv

from neuronsmae.client.spaces import ArenaSource, open_face
from neuronsmae.protocol.errors import InvalidActionError

AgentID = str
ObsDict = dict[str, np.ndarray]
RENDER_MODES = ("rgb_array",)


class ArenaParallelEnv(ParallelEnv[AgentID, ObsDict, Any]):
    """Every controlled robot of an arena as a PettingZoo parallel agent.

    Built like :class:`~neuronsmae.client.gym_env.CoopEnv`: ``env=`` an ``ArenaAPI`` instance
    or a zero-argument factory of one (in-process), or no ``env`` and the ``RM`` arguments
    (``seed``, ``port``, arena options such as ``mode="competitive"``) for a remote arena. The
    environment owns its arena (:meth:`close` closes it; a failed construction leaves an arena
    passed in to the caller). ``contexts`` are every episode's
    reset contexts; ``reset(options={"contexts": ...})`` updates them for one episode.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "neuronsmae_parallel_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": 2.5,
        "is_parallelizable": True,
    }

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
        self.arena, self.layout = open_face(env, rm_kwargs, render_mode, RENDER_MODES)
        layout = self.layout
        self.metadata = {**type(self).metadata, "render_fps": layout.render_fps}
        self.possible_agents = list(layout.agents)
        self.agents: list[AgentID] = []
        # Agent i is robot i (blue first, then red): the arena's per-agent lists and its
        # per-robot ``info["alive"]`` share this index.
        self._robot = {name: i for i, name in enumerate(self.possible_agents)}
        # One space object per agent, built once: PettingZoo requires the same object on
        # every call (so seeding a space sticks), and separate objects keep their RNGs apart.
        self.observation_spaces = {
            a: spaces.Dict(
                {"observation": layout.obs_space(), layout.mask_key: layout.mask_space()}
            )
            for a in self.possible_agents
        }
        self.action_spaces = {a: layout.agent_action_space() for a in self.possible_agents}
        self.state_space = layout.state_space()
        """The global state's space: every robot's pose, HP and bullets and the time."""

    # ---- spaces -------------------------------------------------------------------------

    def observation_space(self, agent: AgentID) -> spaces.Space[Any]:
        return self.observation_spaces[agent]

    def action_space(self, agent: AgentID) -> spaces.Space[Any]:
        return self.action_spaces[agent]

    # ---- PettingZoo API -----------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[AgentID, ObsDict], dict[AgentID, dict[str, Any]]]:
        """Start an episode with every possible agent; ``seed`` re-seeds the arena."""
        contexts = {**self.contexts, **dict((options or {}).get("contexts") or {})}
        obs = self.arena.reset(contexts or None, seed)
        self.agents = list(self.possible_agents)
        return self._observe(obs, self.agents), {a: {} for a in self.agents}

    def step(
        self, actions: Mapping[AgentID, Any]
    ) -> tuple[
        dict[AgentID, ObsDict],
        dict[AgentID, float],
        dict[AgentID, bool],
        dict[AgentID, bool],
        dict[AgentID, dict[str, Any]],
    ]:
        acting = self.agents
        missing = [a for a in acting if a not in actions]
        if missing:
            raise InvalidActionError(f"no action for live agent(s) {missing}")
        layout = self.layout
        joint = [
            layout.to_arena(a, actions[a]) if a in acting else layout.noop()
            for a in self.possible_agents
        ]
        obs, rewards, done, info = self.arena.step(joint)
        alive = list(info["alive"])
        ended = bool(done)
        wiped = ended and layout.annihilated(info)
        terminations = {a: wiped or not alive[self._robot[a]] for a in acting}
        truncations = {a: ended and not terminations[a] for a in acting}
        observations = self._observe(obs, acting)
        reward = {a: float(rewards[self._robot[a]]) for a in acting}
        infos = {a: dict(info) for a in acting}
        self.agents = [a for a in acting if not (terminations[a] or truncations[a])]
        return observations, reward, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The arena's global state (blue-first, independent of observability options)."""
        return np.asarray(self.arena.get_state(), dtype=np.float32)

    def render(self) -> np.ndarray | None:
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

    # ---- helpers ------------------------------------------------------------------------

    def _observe(self, obs: list[np.ndarray], agents: list[AgentID]) -> dict[AgentID, ObsDict]:
        masks = self.arena.get_avail_actions()
        key = self.layout.mask_key
        out = {}
        for a in agents:
            i = self._robot[a]
            out[a] = {
                "observation": np.asarray(obs[i], dtype=np.float32),
                key: np.asarray(masks[i], dtype=np.int8),
            }
        return out


def parallel_env(**kwargs: Any) -> ArenaParallelEnv:
    """PettingZoo's conventional constructor: ``parallel_env(env=lambda: Arena(...))``."""
    return ArenaParallelEnv(**kwargs)
