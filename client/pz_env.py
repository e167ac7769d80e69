"""``ArenaParallelEnv``: the arena as a PettingZoo ``ParallelEnv``, one agent per robot.

For decentralised learners (independent or parameter-shared policies, MAPPO with
:meth:`~ArenaParallelEnv.state`) and for self-play: in ``mode="cooperative"`` the agents are
the blue robots against the arena's bot, in ``mode="competitive"`` blue then red robots.
PettingZoo's three constructors are here: :func:`parallel_env`, :func:`env` (AEC, with
PettingZoo's order-enforcing wrapper) and :func:`raw_env` (AEC, bare). With no arguments
they launch a private unpaced server, stopped on ``close()``; see
:mod:`neuronsmae.client.source` for ``env=``, ``seed``, the other keyword arguments (unknown
ones are refused before anything starts) and Gymnasium's entropy seeding.

PettingZoo semantics, as chosen here (see :mod:`neuronsmae.client.spaces` for the spaces):

* ``masks`` says where the masks go. ``"obs"`` (the default): observations are
  ``Dict({"observation": Box(-1, 1, (d,), float32), <mask>})``, the convention of
  PettingZoo's classic environments, TorchRL's ``PettingZooWrapper`` and the usual
  trainers. ``"rllib"``: ``Dict({"observations": ..., <mask>})``, the keys of RLlib's
  action-masking module. ``"info"``: the observation is the bare ``Box`` and the mask is
  ``infos[agent][<mask>]``, for pipelines that take ``Box`` observations only (SuperSuit's
  ``black_death_v3`` and ``pettingzoo_env_to_vec_env_v1``). ``<mask>`` is ``"action_mask"``
  (``Box(0, 1, (n_actions,), int8)``) for abstract and discrete actions and ``"target_mask"``
  (``(n_enemies,)``) for continuous ones, whose ``Box(4)`` action cannot be sampled with a
  mask.
* A destroyed robot stays an agent until the episode ends (as in SMAC): its mask then
  allows only the no-op, it keeps getting its team's reward, and every agent is terminated
  together when a team is wiped out, or truncated together at the time limit. So
  :attr:`agents` is fixed during an episode, which is what TorchRL's default (an episode
  ends when any agent is done), RLlib and SuperSuit's vector environments expect.
  ``remove_dead=True`` instead terminates a robot in the step it is destroyed and removes it
  from :attr:`agents` for good (the environment then sends its no-op); SuperSuit's
  ``black_death_v3`` turns that back into fixed agents.
* Rewards are per agent: each robot gets its team's reward, as the arena reports it.
* Actions are needed for every agent in :attr:`agents`; actions for other names are ignored.
  A ``step`` after the episode ended (:attr:`agents` empty) returns five empty dicts, as
  PettingZoo's ``aec_to_parallel`` does; SuperSuit's ``black_death_v3`` makes that step
  (it sees the end one step late) before the vector environment resets.
* Infos are numbers and arrays only (:mod:`neuronsmae.client.infos`), from each agent's
  team's point of view, the same keys after ``reset`` as after ``step``;
  :attr:`ArenaParallelEnv.arena_info` is the arena's own last info.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper
from pettingzoo.utils.env import AECEnv, ParallelEnv

from neuronsmae.client.infos import copy_info, start_info, step_info
from neuronsmae.client.source import ArenaSource, FirstSeed, Recipe, open_face
from neuronsmae.client.spaces import face_contexts, reset_contexts
from neuronsmae.client.viewer import HUMAN, RGB_ARRAY, Renderer, render_modes
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError

AgentID = str
MASK_FORMS = {"obs": "observation", "rllib": "observations", "info": None}
"""``masks`` → the key of the observation in its Dict (None: a bare Box, masks in infos)."""


class ArenaParallelEnv(Recipe, ParallelEnv[AgentID, Any, Any]):
    """Every controlled robot of an arena as a PettingZoo parallel agent.

    Built like :class:`~neuronsmae.client.gym_env.CoopEnv` (``env``, ``seed``,
    ``render_mode``, ``contexts``, then ``RM``'s arguments and the arena options, such as
    ``mode="competitive"``), plus ``masks`` and ``remove_dead`` (see the module docstring).
    The environment owns its arena (:meth:`close` closes it; a failed construction leaves an
    arena passed in to the caller). ``contexts`` are every episode's reset contexts;
    ``reset(options={"contexts": ...})`` updates them for one episode.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "name": "neuronsmae_parallel_v0",
        "render_modes": [HUMAN, RGB_ARRAY],
        "render_fps": 2.5,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        env: ArenaSource = None,
        *,
        seed: int | None = None,
        render_mode: str | None = None,
        contexts: Mapping[str, Any] | None = None,
        masks: str = "obs",
        remove_dead: bool = False,
        **kwargs: Any,
    ) -> None:
        if masks not in MASK_FORMS:
            raise InvalidOptionError(f"masks={masks!r}; valid options: {sorted(MASK_FORMS)}")
        Recipe.__init__(self, env=env, seed=seed, render_mode=render_mode, contexts=contexts,
                        masks=masks, remove_dead=remove_dead, **kwargs)  # fmt: skip
        self.render_mode = render_mode
        self.contexts = face_contexts(contexts)
        self.masks, self.remove_dead = masks, bool(remove_dead)
        self.arena, self.layout, seeded = open_face(
            env, seed, kwargs, render_mode, "ArenaParallelEnv"
        )
        layout = self.layout
        self._first_seed = FirstSeed(seeded)
        self.metadata = {
            **type(self).metadata,
            "render_modes": render_modes(),
            "render_fps": layout.render_fps,
        }
        self.possible_agents = list(layout.agents)
        self.agents: list[AgentID] = []
        self._playing = False
        """Whether an episode was started (the arena refuses a step before the first reset)."""
        # Agent i is robot i (blue first, then red): the arena's per-agent lists and its
        # per-robot ``info["alive"]`` share this index.
        self._robot = {name: i for i, name in enumerate(self.possible_agents)}
        self._team = {name: layout.team_of(i) for i, name in enumerate(self.possible_agents)}
        # One space object per agent, built once: PettingZoo requires the same object on
        # every call (so seeding a space sticks), and separate objects keep their RNGs apart.
        key = MASK_FORMS[masks]
        self.observation_spaces: dict[AgentID, spaces.Space[Any]] = {
            a: layout.obs_space() if key is None
            else spaces.Dict({key: layout.obs_space(), layout.mask_key: layout.mask_space()})
            for a in self.possible_agents
        }  # fmt: skip
        self.action_spaces = {a: layout.agent_action_space() for a in self.possible_agents}
        self.state_space = layout.state_space()
        """The global state's space: every robot's pose, HP and bullets and the time."""
        self._renderer = Renderer(self.arena.render, render_mode, layout.render_fps,
                                  "NeuronsMAE")  # fmt: skip
        self.arena_info: dict[str, Any] = {}
        """The arena's own ``info`` of the last step, unchanged; empty after ``reset``."""

    # ---- spaces -------------------------------------------------------------------------

    def observation_space(self, agent: AgentID) -> spaces.Space[Any]:
        return self.observation_spaces[agent]

    def action_space(self, agent: AgentID) -> spaces.Space[Any]:
        return self.action_spaces[agent]

    # ---- PettingZoo API -----------------------------------------------------------------

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[AgentID, Any], dict[AgentID, dict[str, Any]]]:
        """Start an episode with every possible agent; ``seed`` re-seeds the arena."""
        contexts = reset_contexts(self.contexts, options)
        obs = self.arena.reset(contexts or None, self._first_seed(seed))
        self.agents = list(self.possible_agents)
        self._playing = True
        self.arena_info = {}
        start = start_info(self.layout.info, self.arena.get_state())
        observations, masks = self._observe(obs, self.agents)
        self._renderer.update()
        return observations, self._infos(self.agents, dict.fromkeys(self.agents, start), masks)

    def step(
        self, actions: Mapping[AgentID, Any]
    ) -> tuple[
        dict[AgentID, Any],
        dict[AgentID, float],
        dict[AgentID, bool],
        dict[AgentID, bool],
        dict[AgentID, dict[str, Any]],
    ]:
        acting = self.agents
        if not acting and self._playing:  # the episode has ended: nothing acts any more
            return {}, {}, {}, {}, {}
        if not isinstance(actions, Mapping):
            raise InvalidActionError(
                f"actions must be a dict of agent name to action (agents {acting}), got "
                f"{actions!r:.80}"
            )
        missing = [a for a in acting if a not in actions]
        if missing:
            raise InvalidActionError(f"no action for live agent(s) {missing}")
        unknown = [a for a in actions if a not in self.possible_agents]
        if unknown:  # a typo or another team's name: refused, not silently dropped
            raise InvalidActionError(
                f"actions name unknown agent(s) {unknown[:5]!r:.120}; the live agents are {acting}"
            )
        layout = self.layout
        joint = [
            layout.to_arena(a, actions[a]) if a in acting else layout.noop()
            for a in self.possible_agents
        ]
        obs, rewards, done, raw = self.arena.step(joint)
        alive = list(raw["alive"])
        ended = bool(done)
        wiped = ended and layout.annihilated(raw)
        if self.remove_dead:
            terminations = {a: wiped or not alive[self._robot[a]] for a in acting}
        else:
            terminations = dict.fromkeys(acting, wiped)
        truncations = {a: ended and not terminations[a] for a in acting}
        self.arena_info = raw
        state = self.arena.get_state()
        by_team = [step_info(layout.info, raw, state, t, ended and not wiped) for t in (0, 1)]
        observations, masks = self._observe(obs, acting)
        reward = {a: float(rewards[self._robot[a]]) for a in acting}
        infos = self._infos(acting, {a: by_team[self._team[a]] for a in acting}, masks)
        self.agents = [a for a in acting if not (terminations[a] or truncations[a])]
        self._renderer.update()
        return observations, reward, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """The arena's global state (blue-first, independent of observability options)."""
        return np.asarray(self.arena.get_state(), dtype=np.float32)

    def render(self) -> np.ndarray | None:
        """The top-down RGB frame (H × W × 3 uint8) when ``render_mode="rgb_array"``."""
        return self._renderer.render()

    def close(self) -> None:
        """Close the arena (and the server this environment launched); safe to repeat."""
        self._renderer.close()
        self.arena.close()

    # ---- helpers ------------------------------------------------------------------------

    def _observe(
        self, obs: list[np.ndarray], agents: list[AgentID]
    ) -> tuple[dict[AgentID, Any], dict[AgentID, np.ndarray]]:
        """Each agent's observation in the ``masks`` form, and each agent's mask."""
        avail = self.arena.get_avail_actions()
        masks = {a: np.asarray(avail[self._robot[a]], dtype=np.int8) for a in agents}
        key = MASK_FORMS[self.masks]
        out: dict[AgentID, Any] = {}
        for a in agents:
            vector = np.asarray(obs[self._robot[a]], dtype=np.float32)
            out[a] = vector if key is None else {key: vector, self.layout.mask_key: masks[a]}
        return out, masks

    def _infos(
        self,
        agents: list[AgentID],
        numeric: Mapping[AgentID, Mapping[str, Any]],
        masks: Mapping[AgentID, np.ndarray],
    ) -> dict[AgentID, dict[str, Any]]:
        in_info = MASK_FORMS[self.masks] is None
        return {
            a: {**copy_info(numeric[a]), **({self.layout.mask_key: masks[a]} if in_info else {})}
            for a in agents
        }


def parallel_env(**kwargs: Any) -> ArenaParallelEnv:
    """PettingZoo's parallel constructor: ``parallel_env()`` (a private served arena),
    ``parallel_env(env="neuronsmae.server:Arena")`` (in process), ``parallel_env(env=lambda:
    Arena(...))``, with the arguments of :class:`ArenaParallelEnv`."""
    return ArenaParallelEnv(**kwargs)


def raw_env(**kwargs: Any) -> AECEnv[AgentID, Any, Any]:
    """PettingZoo's bare AEC constructor: the parallel environment seen one agent at a time
    (PettingZoo's ``parallel_to_aec`` conversion, without its wrappers)."""
    return parallel_to_aec_wrapper(ArenaParallelEnv(**kwargs))


def env(**kwargs: Any) -> AECEnv[AgentID, Any, Any]:
    """PettingZoo's AEC constructor: :func:`raw_env` in PettingZoo's order-enforcing
    wrapper (an error, not a wrong result, for a call out of order)."""
    return wrappers.OrderEnforcingWrapper(raw_env(**kwargs))
