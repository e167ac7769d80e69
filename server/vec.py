"""``VecArena``: K arenas in this process, stepped together, with next-step autoreset.

The in-process side of :class:`~neuronsmae.protocol.interface.VecArenaAPI` (the class
docstring there states the contract: shapes, seeds, autoreset). A vector server holds one
``VecArena`` and answers ``vreset``/``vstep``/``vget`` from it; trainers and tests use it
directly where they would use a ``VecRM``.

A request is checked for every arena before any arena moves, so one arena's bad action or
context refuses the whole request and changes nothing. Errors keep their type and name the
arena, however many there are (``arena 0`` of one too):
``InvalidActionError("arena 3: agent 1: action 9 is out of range; valid: [0, 7]")``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from neuronsmae.protocol.defaults import DEFAULT_SEED
from neuronsmae.protocol.errors import (
    ClosedError,
    InvalidActionError,
    NeuronsMAEError,
    ResetNeededError,
)
from neuronsmae.protocol.interface import (
    VecArenaAPI,
    check_seeds,
    count_option,
    first_seed,
    inherit_docstrings,
    per_arena,
    plain_contexts,
    seeds_per_arena,
)
from neuronsmae.protocol.messages import MAX_ARENAS
from neuronsmae.server.arena import Arena
from neuronsmae.server.contexts import check_seed, parse_contexts

ContextsArg = Mapping[str, Any] | Sequence[Mapping[str, Any] | None] | None


@contextmanager
def _in_arena(i: int) -> Iterator[None]:
    """Re-raise arena ``i``'s typed error as the same type, its message prefixed with the
    arena; the arena's own error is its ``__cause__`` (see :func:`as_the_arena`)."""
    try:
        yield
    except NeuronsMAEError as exc:
        raise type(exc)(f"arena {i}: {exc}") from exc


@contextmanager
def as_the_arena() -> Iterator[None]:
    """Re-raise an error that names one arena as that arena's own (without ``arena i:``).

    A one-arena server's ``reset`` and ``step`` go through its ``VecArena`` but answer as
    ``Arena.reset`` and ``Arena.step`` do in process; its ``vreset`` and ``vstep`` name
    arena 0, as every vector message names the arena."""
    try:
        yield
    except NeuronsMAEError as exc:
        own = exc.__cause__
        if type(own) is type(exc):
            raise own from None
        raise


@inherit_docstrings
class VecArena(VecArenaAPI):
    """``num_envs`` arenas with seeds ``seed, seed + 1, ...`` and the same ``**options``.

    ``factory`` builds one arena (``Arena`` by default; the server passes its own).
    ``seed`` is an integer (None is refused, as ``Arena(seed=None)`` is) and ``num_envs`` a
    Python or NumPy integer in [1, 64]; otherwise ``InvalidOptionError``.

    ``step`` checks the rows of the arenas that step in the call only: an inactive or
    autoresetting arena's row is ignored (see ``VecArenaAPI.step``), exactly as a vector
    server and a ``VecRM`` over any number of servers do.
    """

    def __init__(
        self,
        seed: int = DEFAULT_SEED,
        num_envs: int = 1,
        *,
        factory: Callable[..., Arena] = Arena,
        **options: Any,
    ) -> None:
        num_envs = count_option("num_envs", num_envs, 1, MAX_ARENAS)
        self.num_envs = num_envs
        self.seed = first_seed(seed, num_envs)
        self.arenas: list[Arena] = []
        try:
            for i in range(num_envs):
                self.arenas.append(factory(seed=self.seed + i, **options))
        except BaseException:
            self.close()
            raise
        info = self.arenas[0].get_env_info()
        n, d, s = int(info["n_agents"]), int(info["obs_shape"]), int(info["state_shape"])
        self._info = {**info, "num_envs": num_envs}
        self._obs = np.zeros((num_envs, n, d), np.float32)
        self._state = np.zeros((num_envs, s), np.float32)
        self._avail = np.zeros((num_envs, n, int(info["n_actions"])), np.int8)
        self._contexts: list[dict[str, Any] | None] = [None] * num_envs
        """The contexts each arena was last reset with: an autoreset's default."""
        self._done = np.ones(num_envs, dtype=bool)
        """Whose episode has ended (or never started): the next step resets them."""
        self._started = False
        self._closed = False

    # ---- VecArenaAPI ---------------------------------------------------------------------

    def reset(self, contexts: ContextsArg = None, seed: Any = None) -> np.ndarray:
        self._need_open("reset()")
        k = self.num_envs
        per_contexts = self._contexts_per_arena(contexts)
        seeds = self._seeds_per_arena(seed)
        for i in range(k):
            self._check_reset(i, per_contexts[i], seeds[i])
        for i in range(k):
            self._reset_one(i, per_contexts[i], seeds[i])
        self._started = True
        return self._obs.copy()

    def step(
        self,
        actions: Any,
        *,
        seeds: Sequence[int | None] | None = None,
        contexts: Sequence[Mapping[str, Any] | None] | None = None,
        active: Sequence[bool] | np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        self._need_reset("step()")
        k = self.num_envs
        rows = self._rows(actions)
        on = self._flags(active)
        seeds = [None] * k if seeds is None else check_seeds(seeds, k)
        contexts = self._entries("contexts", contexts)
        resetting = on & self._done
        checked: dict[int, list[Any]] = {}
        for i in range(k):  # check everything first: a refused request changes no arena
            if contexts[i] is not None or seeds[i] is not None:  # given for any arena: checked
                self._check_reset(i, contexts[i], seeds[i])
            if on[i] and not resetting[i]:
                with _in_arena(i):
                    checked[i] = self.arenas[i].check_actions(rows[i])
        rewards = np.zeros(self._obs.shape[:2], dtype=np.float64)
        dones = np.zeros(k, dtype=bool)
        infos: list[dict[str, Any]] = [{} for _ in range(k)]
        for i in range(k):
            if resetting[i]:
                self._reset_one(i, contexts[i] or self._contexts[i], seeds[i])
            elif on[i]:
                arena = self.arenas[i]
                _, reward, done, infos[i] = arena.step(checked[i])
                rewards[i] = reward
                dones[i] = self._done[i] = done
                self._remember(i)
        return self._obs.copy(), rewards, dones, infos

    def get_obs(self) -> np.ndarray:
        self._need_reset("get_obs()")
        return self._obs.copy()

    def get_state(self) -> np.ndarray:
        self._need_reset("get_state()")
        return self._state.copy()

    def get_avail_actions(self) -> np.ndarray:
        self._need_reset("get_avail_actions()")
        return self._avail.copy()

    def get_env_info(self) -> dict[str, Any]:
        return dict(self._info)

    def close(self) -> None:
        self._closed = True
        for arena in self.arenas:
            arena.close()

    # ---- helpers -------------------------------------------------------------------------

    def _need_open(self, what: str) -> None:
        if self._closed:
            raise ClosedError(f"{what} on closed arenas; make a new VecArena")

    def _need_reset(self, what: str) -> None:
        self._need_open(what)
        if not self._started:
            raise ResetNeededError(f"{what} needs an episode: call reset() first")

    def _check_reset(self, i: int, contexts: Mapping[str, Any] | None, seed: Any) -> None:
        with _in_arena(i):
            parse_contexts(contexts)
            if seed is not None:
                check_seed(seed)

    def _reset_one(self, i: int, contexts: Mapping[str, Any] | None, seed: Any) -> None:
        self.arenas[i].reset(contexts, None if seed is None else int(seed))
        self._contexts[i] = plain_contexts(contexts)
        self._done[i] = False
        self._remember(i)

    def _remember(self, i: int) -> None:
        """Copy arena ``i``'s observations, state and masks into the stacked arrays."""
        arena = self.arenas[i]
        if self._obs.shape[1]:  # "bots" mode has no agents, hence no rows
            self._obs[i] = arena.get_obs()
            self._avail[i] = arena.get_avail_actions()
        self._state[i] = arena.get_state()

    def _contexts_per_arena(self, contexts: ContextsArg) -> list[Mapping[str, Any] | None]:
        if contexts is None or isinstance(contexts, Mapping):
            return [contexts] * self.num_envs
        return self._entries("contexts", contexts)

    def _seeds_per_arena(self, seed: Any) -> list[Any]:
        return seeds_per_arena(seed, self.num_envs)

    def _entries(self, name: str, values: Any) -> list[Any]:
        """One entry (or None) per arena, as a list; None → all None."""
        return [None] * self.num_envs if values is None else per_arena(name, values, self.num_envs)

    def _rows(self, actions: Any) -> Sequence[Any]:
        ok = (isinstance(actions, np.ndarray) and actions.ndim >= 1) or isinstance(actions, list)
        if not ok:
            raise InvalidActionError(
                f"actions must be a list or an array with one row per arena "
                f"({self.num_envs}), got {type(actions).__name__}"
            )
        if len(actions) != self.num_envs:
            raise InvalidActionError(
                f"actions must have {self.num_envs} rows (one per arena), got {len(actions)}"
            )
        return actions

    def _flags(self, active: Sequence[bool] | np.ndarray | None) -> np.ndarray:
        if active is None:
            return np.ones(self.num_envs, dtype=bool)
        flags = np.asarray(active)
        if flags.shape != (self.num_envs,) or flags.dtype != np.bool_:
            raise InvalidActionError(
                f"active must hold {self.num_envs} booleans (one per arena), got {active!r:.80}"
            )
        return flags
