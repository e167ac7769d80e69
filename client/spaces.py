"""What the Gymnasium and PettingZoo faces share: the arena's layout as spaces, and conversions.

Every face (:mod:`~neuronsmae.client.gym_env`, :mod:`~neuronsmae.client.vec_env`,
:mod:`~neuronsmae.client.agents_env`, :mod:`~neuronsmae.client.pz_env`,
:mod:`~neuronsmae.client.smac`) wraps an :class:`~neuronsmae.protocol.interface.ArenaAPI` —
the in-process ``Arena`` or the remote ``RM`` — or a vector of them, and must agree on how
an arena's options become spaces, how a policy's action becomes the arena's action, where
masks live and when an episode is terminated rather than truncated. Keeping those rules
here means the faces cannot drift apart (:mod:`~neuronsmae.client.source` says where the
arena comes from, :mod:`~neuronsmae.client.infos` what the infos hold).

Conventions (every face):

* Observations are the arena's float32 vectors, every value in [-1, 1].
* Abstract and discrete actions are ``Discrete(n_actions)`` per agent; the availability mask
  over those choices is called ``"action_mask"`` (int8, 1 = allowed), the name every
  Gymnasium/PettingZoo tool passes to ``space.sample(mask=...)``.
* Continuous actions are ``Box(4)`` per agent: ``(vx, vy, omega, target)`` with
  ``vx, vy ∈ [-2, 2]`` m/s, ``omega ∈ [-1.75, 1.75]`` rad/s (``V_MAX`` and ``W_MAX`` of
  :mod:`neuronsmae.protocol.env_info`) and ``target ∈ [0, n_enemies]``
  read as a bin: enemy ``i`` is any value in ``[i, i + 1)`` (the upper edge ``n_enemies``
  counts as the last enemy). Equal-width bins let an unsquashed Gaussian or a tanh-scaled
  policy pick every enemy equally easily; an exact integer ``i`` still means enemy ``i``.
  Its mask covers the target only, so it is called ``"target_mask"``: a mask named
  ``"action_mask"`` would make the standard tools call ``Box.sample(mask=...)``, which fails.
* An episode that ends with a team wiped out is *terminated*; one that ends at the time
  limit with both teams standing is *truncated* (SMAC's convention, ``episode_limit``),
  although the referee decides the game there (docs/ecosystem.md, "Episodes").
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from gymnasium import spaces

from neuronsmae.protocol import env_info
from neuronsmae.protocol.actions import check_sequence, holds_numbers
from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.protocol.errors import InvalidActionError, InvalidOptionError
from neuronsmae.protocol.interface import ArenaAPI, VecArenaAPI

PHYSICS_HZ = 50
"""Physics steps per simulated second (1000 steps = 20 s, docs/options.md): sets render_fps."""
MOTION_HIGH = np.array(env_info.MOTION_HIGH, dtype=np.float32)
MOTION_LOW = -MOTION_HIGH
"""Bounds of (vx, vy, omega) of a continuous action, as the arena validates them (float32;
``EnvInfo.motion_bounds`` gives the same as floats)."""
ACTION_MASK = "action_mask"
TARGET_MASK = "target_mask"


@dataclass(frozen=True)
class Layout:
    """The shape of an arena's task, read once from ``get_env_info`` (fixed by its options)."""

    info: EnvInfo
    """The arena's ``get_env_info()``, parsed."""

    @classmethod
    def of(cls, arena: ArenaAPI | VecArenaAPI) -> Layout:
        """The layout of ``arena`` (one arena, or every arena of a vector: they share it)."""
        layout = cls(EnvInfo.from_dict(arena.get_env_info()))
        if not layout.agents:
            raise InvalidOptionError(
                f"mode={layout.mode!r} leaves no robot to control; use 'cooperative' or "
                "'competitive'"
            )
        return layout

    @property
    def agents(self) -> tuple[str, ...]:
        """Controlled robots in the arena's order (blue first), e.g. ``("blue_0", "blue_1")``."""
        return self.info.agents

    @property
    def kind(self) -> str:
        """The arena's action space option: "abstract", "discrete" or "continuous"."""
        return self.info.action_space

    @property
    def n_actions(self) -> int:
        """Flat discrete choices per agent (for continuous: target enemies)."""
        return self.info.n_actions

    @property
    def n_enemies(self) -> int:
        return self.info.n_enemies

    @property
    def obs_dim(self) -> int:
        return self.info.obs_shape

    @property
    def state_dim(self) -> int:
        return self.info.state_shape

    @property
    def episode_limit(self) -> int:
        """Decisions per episode at most."""
        return self.info.episode_limit

    @property
    def decision_steps(self) -> int:
        return self.info.decision_steps

    @property
    def mode(self) -> str:
        return self.info.mode

    @property
    def continuous(self) -> bool:
        return self.kind == "continuous"

    @property
    def mask_key(self) -> str:
        """Where masks go: ``"action_mask"``, or ``"target_mask"`` for continuous actions."""
        return TARGET_MASK if self.continuous else ACTION_MASK

    @property
    def render_fps(self) -> float:
        """Decisions per simulated second: one rendered frame per decision plays in real time."""
        return PHYSICS_HZ / self.decision_steps

    # ---- spaces -------------------------------------------------------------------------

    def obs_space(self, n_agents: int | None = None) -> spaces.Box:
        """One agent's observation, or ``n_agents`` of them stacked row by row."""
        shape = (self.obs_dim,) if n_agents is None else (n_agents, self.obs_dim)
        return spaces.Box(-1.0, 1.0, shape, np.float32)

    def mask_space(self) -> spaces.Box:
        """One agent's mask (int8 0/1), PettingZoo's classic ``action_mask`` space."""
        return spaces.Box(0, 1, (self.n_actions,), np.int8)

    def state_space(self) -> spaces.Box:
        return spaces.Box(-1.0, 1.0, (self.state_dim,), np.float32)

    def motion_box(self, n_agents: int | None = None) -> spaces.Box:
        """Continuous actions: ``(vx, vy, omega, target)`` per row, see the module docstring."""
        lower, upper = self.info.motion_bounds  # (vx, vy, omega) as the arena checks them
        low = np.array([*lower, 0.0], dtype=np.float32)
        high = np.array([*upper, self.n_enemies], dtype=np.float32)
        if n_agents is not None:
            low, high = np.tile(low, (n_agents, 1)), np.tile(high, (n_agents, 1))
        return spaces.Box(low, high, dtype=np.float32)

    def agent_action_space(self) -> spaces.Space[Any]:
        if self.continuous:
            return self.motion_box()
        return spaces.Discrete(self.n_actions)

    # ---- conversions --------------------------------------------------------------------

    def noop(self) -> Any:
        """The action sent for a robot nobody controls any more (a destroyed one): stand
        still, aim at the first enemy — the only action its mask allows."""
        return [0.0, 0.0, 0.0, 0] if self.continuous else 0

    def to_arena(self, agent: str, action: Any) -> Any:
        """A policy's action for ``agent`` → the arena's: plain Python numbers for the wire.

        Range and type errors are left to the arena, which names the bound, except the
        target bin, which only exists on this side.
        """
        if not self.continuous:
            if isinstance(action, np.ndarray) and action.shape == ():
                return action.item()
            return action.item() if isinstance(action, np.generic) else action
        arr = np.asarray(action, dtype=np.float64) if holds_numbers(action) else None
        if arr is None or arr.shape != (4,) or not np.isfinite(arr).all():
            raise InvalidActionError(
                f"{agent}: a continuous action is 4 finite numbers (vx, vy, omega, target), "
                f"got {action!r}"
            )
        target = arr[3]
        if not 0.0 <= target <= self.n_enemies:
            raise InvalidActionError(
                f"{agent}: target={target} is outside [0, {self.n_enemies}] (enemy i is the bin "
                "[i, i + 1))"
            )
        index = min(int(np.floor(target)), self.n_enemies - 1)
        return [float(arr[0]), float(arr[1]), float(arr[2]), index]

    def joint_to_arena(self, joint: Any) -> np.ndarray:
        """:meth:`to_arena` for stacked actions (``[..., n]``, or ``[..., n, 4]`` for
        continuous actions) at once: the arena's rows, targets read as bins."""
        if not self.continuous:
            return np.asarray(joint)
        arr = np.array(joint, dtype=np.float64)
        if arr.ndim < 2 or arr.shape[-1] != 4 or not np.isfinite(arr).all():
            raise InvalidActionError(
                "continuous actions are rows of 4 finite numbers (vx, vy, omega, target), got "
                f"shape {arr.shape}"
            )
        target = arr[..., 3]
        bad = np.argwhere((target < 0.0) | (target > self.n_enemies))
        if len(bad):
            where = tuple(int(i) for i in bad[0])
            raise InvalidActionError(
                f"action {where}: target={target[where]} is outside [0, {self.n_enemies}] "
                "(enemy i is the bin [i, i + 1))"
            )
        arr[..., 3] = np.minimum(np.floor(target), self.n_enemies - 1)
        return arr

    def team_of(self, agent: int) -> int:
        """The team of agent ``agent`` (0 blue, 1 red): agents are the blue robots, then (in
        competitive mode) the red ones."""
        return 0 if agent < self.info.state.n_blue else 1

    def team_split(self, alive: list[bool]) -> tuple[list[bool], list[bool]]:
        """Blue's and red's ``alive`` flags (red is the enemy team of width ``n_enemies``)."""
        return alive[: len(alive) - self.n_enemies], alive[len(alive) - self.n_enemies :]

    def annihilated(self, info: Mapping[str, Any]) -> bool:
        """Whether a team has no robot left: the episode's terminal state, as opposed to the
        time limit. Read from ``alive`` rather than ``t`` so a wipe-out on the last physics
        step still counts as terminal."""
        blue, red = self.team_split(list(info["alive"]))
        return not any(blue) or not any(red)


def per_agent_actions(actions: Any, n_agents: int, discrete: bool = True) -> list[Any]:
    """One action per agent from a sequence of ``n_agents``; discrete ones as ``int()`` of
    each (Python or numpy integers, 0-d or one-element tensors). ``InvalidActionError``
    names what is wrong and which agent."""
    check_sequence(actions, n_agents)  # not a mapping, set, string, scalar (as the arena)
    count = len(actions)
    if count != n_agents:
        raise InvalidActionError(f"expected {n_agents} actions (one per agent), got {count}")
    if not discrete:
        return list(actions)
    return [_discrete_action(i, a) for i, a in enumerate(actions)]


def _discrete_action(agent: int, action: Any) -> int:
    """``int()`` of one discrete action, refusing what it would change: a fraction (0.5 was
    taken as 0) or a bool, as the arena does."""
    try:
        value = action.item() if hasattr(action, "item") else action  # NumPy, torch scalars
        whole = int(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise InvalidActionError(
            f"agent {agent}: an action is an integer (anything int() accepts), got {action!r:.80}"
        ) from exc
    if isinstance(value, (bool, str, bytes)) or (isinstance(value, float) and value != whole):
        raise InvalidActionError(
            f"agent {agent}: an action is an integer (a whole number), got {action!r:.80}"
        )
    return whole


RESET_OPTIONS = ("contexts",)
"""The keys a face's ``reset(options=...)`` reads. Other keys are ignored, as Gymnasium
and PettingZoo expect of an environment (``pettingzoo.test.parallel_api_test`` passes
one of its own)."""


def face_contexts(contexts: Any) -> dict[str, Any]:
    """A face's own contexts (its ``contexts=`` argument, applied at every reset) as a
    dict; None is none, anything but a mapping an ``InvalidOptionError``. Their keys and
    values are checked by the arena at the first reset, against its context table."""
    if contexts is None:
        return {}
    if not isinstance(contexts, Mapping):
        raise InvalidOptionError(
            f"contexts must be a dict of context names to values, got {contexts!r:.80}"
        )
    return dict(contexts)


def reset_contexts(base: Mapping[str, Any], options: Any) -> dict[str, Any]:
    """The contexts of an episode: the face's own ``base`` updated by
    ``options["contexts"]``. ``options`` that is not None or a mapping, or contexts that
    are not a mapping, are an ``InvalidOptionError`` naming what is valid."""
    if options is None:
        return dict(base)
    if not isinstance(options, Mapping):
        raise InvalidOptionError(
            f"reset options must be a dict (read: {list(RESET_OPTIONS)}), got {options!r:.80}"
        )
    contexts = options.get("contexts")
    if contexts is not None and not isinstance(contexts, Mapping):
        raise InvalidOptionError(
            f"options['contexts'] must be a dict of context names to values, got {contexts!r:.80}"
        )
    return {**base, **dict(contexts or {})}
