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

from neuronsmae.protocol.actions import is_sequence
from neuronsmae.protocol.errors import (
    InvalidContextError,
    InvalidOptionError,
    NeuronsMAEError,
)
from neuronsmae.protocol.messages import MAX_SEED, max_first_seed

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
        """Release the arena's resources; safe to call more than once. Afterwards
        ``reset``, ``step``, the ``get_*`` reads of the scene and ``render`` raise a typed
        error: ``ClosedError`` in process, ``ServerUnavailableError`` ("is closed") from a
        client (``get_env_info`` may still answer from what is known)."""

    def __enter__(self) -> ArenaAPI:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def inherit_docstrings(cls: type) -> type:
    """Class decorator: each method overriding a contract method (of :class:`ArenaAPI` or
    :class:`VecArenaAPI`) without a docstring of its own gets the contract's, so
    ``help(RM.step)``, ``help(Arena.step)`` and a wrapper's ``step`` all tell the same
    contract."""
    contracts = [c for c in cls.__mro__ if c.__name__ in ("ArenaAPI", "VecArenaAPI")]
    for contract in contracts:
        for name in contract.__abstractmethods__:
            method = cls.__dict__.get(name)
            if method is not None and not method.__doc__:
                method.__doc__ = getattr(contract, name).__doc__
    return cls


def per_arena(
    name: str, values: Any, num_envs: int, error: type[Exception] = InvalidContextError
) -> list[Any]:
    """``values`` as a list of one entry per arena (the vector calls' rule for ``seeds``,
    ``contexts`` and action rows); ``error`` (naming ``name``) when it is not a sequence of
    ``num_envs`` entries."""
    if not is_sequence(values):
        raise error(
            f"{name} must be a sequence of {num_envs} entries (one per arena, or None), "
            f"got {values!r:.80}"
        )
    if len(values) != num_envs:
        raise error(f"{name} must have {num_envs} entries (one per arena), got {len(values)}")
    return list(values)


def _is_int(value: Any) -> bool:
    """An integer (Python or NumPy) that is not a bool."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def count_option(name: str, value: Any, lo: int, hi: int | None = None) -> int:
    """An integer option such as ``num_envs`` (Python or NumPy integer, never a bool) as an
    int in ``[lo, hi]`` (no upper bound when ``hi`` is None), or ``InvalidOptionError``
    naming it and what is valid."""
    valid = f"[{lo}, {hi}]" if hi is not None else f">= {lo}"
    if not _is_int(value) or not lo <= int(value) <= (hi if hi is not None else int(value)):
        raise InvalidOptionError(f"{name} must be an integer {valid}, got {value!r:.80}")
    return int(value)


def first_seed(seed: Any, num_envs: int) -> int:
    """A vector's ``seed`` option as an int: arena i is seeded ``seed + i``, so the seed is
    an integer in [0, max_first_seed(num_envs)]. None is refused, as ``Arena(seed=None)``
    is: ``RM(seed=None)`` keeps a server's own ``--seed``, which cannot give the arenas of
    several servers consecutive seeds. ``InvalidOptionError`` otherwise."""
    top = max_first_seed(num_envs)
    if not _is_int(seed) or not 0 <= int(seed) <= top:
        raise InvalidOptionError(
            f"seed must be an integer in [0, {top}] (arena i is seeded seed + i), got {seed!r:.80}"
        )
    return int(seed)


def seed_value(
    seed: Any, where: str = "", error: type[NeuronsMAEError] = InvalidContextError
) -> int:
    """One reset seed as an int in [0, MAX_SEED] (Python or NumPy integer, never a bool),
    or ``error`` (its message starting with ``where``) saying what is valid."""
    if not _is_int(seed):
        raise error(f"{where}seed must be an integer in [0, {MAX_SEED}], got {seed!r:.80}")
    if not 0 <= int(seed) <= MAX_SEED:
        raise error(f"{where}seed {int(seed)} is out of range; valid: [0, {MAX_SEED}]")
    return int(seed)


def check_series_seed(seed: Any, episodes: int) -> int:
    """The seed of episode 0 of a series (Python or NumPy integer) as an int: episode ``i``
    is reset with ``seed + i``, which must stay within 2⁶³ − 1; ``InvalidContextError``
    naming ``seed``, ``episodes`` and the valid range otherwise."""
    value = seed_value(seed)
    top = max_first_seed(episodes)
    if value > top:
        raise InvalidContextError(
            f"seed={value} with episodes={episodes}: episode i is reset with seed + i, which "
            f"must stay within {MAX_SEED}; seed must be in [0, {top}]"
        )
    return value


def seeds_per_arena(seed: Any, num_envs: int) -> list[int | None]:
    """A vector ``reset``'s ``seed`` as one seed (or None) per arena: None (every arena
    continues its RNG), an int (arena i gets ``seed + i``) or a sequence of ``num_envs``
    ints or None. ``InvalidContextError`` names the arena and what is valid."""
    if seed is None:
        return [None] * num_envs
    if _is_int(seed):
        first, top = seed_value(seed), max_first_seed(num_envs)
        if first > top:
            raise InvalidContextError(
                f"seed must be in [0, {top}] (arena i gets seed + i), got {first}"
            )
        return [first + i for i in range(num_envs)]
    if not is_sequence(seed):
        raise InvalidContextError(
            f"seed must be an int (arena i gets seed + i) or a sequence of {num_envs} ints "
            f"or None (one per arena), got {type(seed).__name__} {seed!r:.80}"
        )
    return check_seeds(seed, num_envs, "seed")


def check_seeds(seeds: Any, num_envs: int, name: str = "seeds") -> list[int | None]:
    """``seeds`` of a vector ``step`` (or a ``reset``'s list): one int or None per arena,
    each checked (:func:`seed_value`) whether or not that arena resets in this call."""
    entries = per_arena(name, seeds, num_envs)
    return [None if s is None else seed_value(s, f"arena {i}: ") for i, s in enumerate(entries)]


def plain_contexts(contexts: Any, where: str = "") -> dict[str, Any] | None:
    """A reset's ``contexts`` (a mapping of context key to value, or None) as a plain dict
    whose NumPy scalars are Python values (``np.float32(0.2)`` → ``0.2``, ``np.bool_`` →
    ``bool``, refused later as a bool is), so that they are checked, stored and sent as
    the numbers they are. ``InvalidContextError`` (its message starting with ``where``)
    when ``contexts`` is not a mapping."""
    if contexts is None:
        return None
    if not isinstance(contexts, Mapping):
        raise InvalidContextError(
            f"{where}contexts must be a mapping of context key to value (or None), got "
            f"{type(contexts).__name__} {contexts!r:.80}"
        )
    return {k: v.item() if isinstance(v, np.generic) else v for k, v in contexts.items()}


def shares_of(num_envs: int, parts: int) -> list[int]:
    """How many of ``num_envs`` consecutive arenas each of ``parts`` parts holds (a
    ``VecRM``'s servers, a rollout worker's groups): as even as possible, the first parts
    taking one more."""
    base, extra = divmod(num_envs, parts)
    return [base + (1 if j < extra else 0) for j in range(parts)]


class StepHandle:
    """A ``step`` in progress (:meth:`VecArenaAPI.step_async`): :meth:`result` waits for it
    and returns what ``step`` returns."""

    def __init__(self, value: Any) -> None:
        self._value = value

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        return self._value


class VecArenaAPI(abc.ABC):
    """K arenas stepped together: the contract of the in-process ``VecArena`` and the remote
    ``VecRM``, so that trainers and tests can swap them.

    Arena ``i`` of a vector built with seed ``s`` is seeded ``s + i`` and plays exactly like
    ``Arena(seed=s + i)`` given the same contexts and actions. Results are stacked numpy
    arrays with the arena index first: ``obs [K, n_agents, obs_dim]`` float32,
    ``rewards [K, n_agents]`` float64, ``dones [K]`` bool, ``state [K, state_dim]`` float32,
    ``avail_actions [K, n_agents, n_actions]`` int8, and ``infos``, a list of K dicts.

    Autoreset: Gymnasium 1.x's *next-step* mode. An arena whose episode ends at step ``t``
    reports ``done`` with its final observation, state and masks in that step's arrays;
    the next :meth:`step` resets it instead of stepping it (its action row is ignored) and
    returns its first observation, reward 0, ``done`` False and an empty info. That reset
    uses the arena's entry of ``seeds`` and ``contexts`` given to that :meth:`step` when
    there is one, else the arena's own RNG and the contexts of its previous reset.
    """

    num_envs: int
    """K, the number of arenas."""

    @abc.abstractmethod
    def reset(
        self,
        contexts: Mapping[str, Any] | Sequence[Mapping[str, Any] | None] | None = None,
        seed: int | Sequence[int | None] | None = None,
    ) -> np.ndarray:
        """Reset every arena; return ``obs [K, n_agents, obs_dim]``.

        ``contexts`` is one mapping for all arenas or one (or None) per arena; ``seed`` None
        (every arena continues its RNG), an int (arena i gets ``seed + i``, as Gymnasium's
        vector environments do) or one seed (or None) per arena. Raises
        ``InvalidContextError`` naming the arena and the key; a refused reset changes no
        arena.
        """

    @abc.abstractmethod
    def step(
        self,
        actions: Any,
        *,
        seeds: Sequence[int | None] | None = None,
        contexts: Sequence[Mapping[str, Any] | None] | None = None,
        active: Sequence[bool] | np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        """One decision in every arena: ``actions`` has one row per arena (``[K, n_agents]``
        ints, or ``[K, n_agents, 4]`` for continuous actions).

        Returns ``(obs, rewards, dones, infos)``. ``seeds`` and ``contexts`` (one entry or
        None per arena) serve the arenas that autoreset in this step (see the class
        docstring). Arenas where ``active`` is False are left untouched: not stepped, not
        reset, reward 0, ``done`` False, empty info. Raises ``InvalidActionError`` naming
        the arena and agent, ``InvalidContextError``, or ``ResetNeededError`` before the
        first :meth:`reset`; a refused request changes no arena.

        What is checked, the same in process, on one server or on several: the action row
        of every arena that steps in this call; the row of an arena that does not step (not
        ``active``, or autoresetting) is ignored, unchecked, as Gymnasium's next-step
        autoreset ignores the action after a done, and so are the actions of the team a bot
        drives (``bot_team``). Every entry of ``seeds`` and ``contexts`` is checked whether or
        not its arena resets in this call, so a typo is refused at once, not at the reset.
        """

    def step_async(
        self,
        actions: Any,
        *,
        seeds: Sequence[int | None] | None = None,
        contexts: Sequence[Mapping[str, Any] | None] | None = None,
        active: Sequence[bool] | np.ndarray | None = None,
    ) -> StepHandle:
        """Start :meth:`step` and return a handle whose ``result()`` gives what ``step``
        returns. A remote vector sends the request and returns at once, so the caller can
        work meanwhile (a rollout worker computes the actions of its other arenas while the
        server steps these, with ``active`` splitting them); in process the step runs here.
        Several steps may be in flight; call their ``result()`` in the order they were
        started (each leaves ``get_obs`` and the other reads where its reply left them)."""
        return StepHandle(self.step(actions, seeds=seeds, contexts=contexts, active=active))

    @abc.abstractmethod
    def get_obs(self) -> np.ndarray:
        """``[K, n_agents, obs_dim]``: what the last reset or step returned."""

    @abc.abstractmethod
    def get_state(self) -> np.ndarray:
        """``[K, state_dim]``: every arena's global state (see ``ArenaAPI.get_state``)."""

    @abc.abstractmethod
    def get_avail_actions(self) -> np.ndarray:
        """``[K, n_agents, n_actions]`` int8 masks (see ``ArenaAPI.get_avail_actions``)."""

    @abc.abstractmethod
    def get_env_info(self) -> dict[str, Any]:
        """One arena's ``get_env_info()`` (every arena has the same options) plus
        ``num_envs``."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release every arena (and servers this object launched); safe to repeat. Afterwards
        the other calls raise a typed error, as ``ArenaAPI.close`` says."""

    def __enter__(self) -> VecArenaAPI:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
