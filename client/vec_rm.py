"""``VecRM``: K served arenas stepped together, one request per server per decision.

``VecRM`` implements :class:`~neuronsmae.protocol.interface.VecArenaAPI` (the contract:
shapes, seeds, next-step autoreset) over one or several ``neuronsmae-server --arenas``
processes, and plays exactly like the in-process ``VecArena`` with the same seed: arena
``i`` is seeded ``seed + i`` whichever server holds it.

Why: one query per decision costs the client a Zenoh round trip per decision whatever
the server does. One ``vstep`` carries the actions of all the server's arenas and one reply
all their results as stacked arrays, so that cost is paid once per K decisions.

Several servers (``port=[p1, p2, ...]`` or ``servers=m`` private ones) hold consecutive
shares of the arenas (as even as possible, the first servers taking the extra ones); a
request goes to every server at once and the replies are gathered, so the servers step
their shares in parallel; a server none of whose arenas is ``active`` in a step is not
asked (its reply is known: nothing moved). A request that one server would refuse (a bad
action, context or seed) is refused here before anything is sent, so no arena moves: the
checks use the layout of ``get_env_info`` and the servers' context table.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from neuronsmae.client.connection import Call, Connection
from neuronsmae.client.spaces import MOTION_HIGH
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    ResetNeededError,
)
from neuronsmae.protocol.interface import (
    StepHandle,
    VecArenaAPI,
    inherit_docstrings,
    per_arena,
    shares_of,
)
from neuronsmae.protocol.launch import ServerCommand, check_launch, ports_of
from neuronsmae.protocol.messages import (
    MAX_ARENAS,
    MAX_SEED,
    Configure,
    Contexts,
    OkReply,
    VGet,
    VReset,
    VStep,
)

STACKED = ("obs", "state", "avail_actions")
"""What every vector reply carries, stacked over the server's arenas."""


@inherit_docstrings
class VecRM(VecArenaAPI):
    """``num_envs`` remote arenas on one or several servers.

    ``port=None`` (the default) launches ``servers`` private servers on free loopback ports
    (one by default), stopped by :meth:`close`; a port or a list of ports uses the servers
    there, launching one on a port where nothing listens on a local ``host`` (with
    ``launch``). A running server must hold exactly its share of the arenas
    (``neuronsmae-server --arenas``), else ``InvalidOptionError`` says what it holds.
    ``seed`` and ``**options`` are those of ``VecArena(seed, num_envs, **options)``;
    ``host``, ``timeout``, ``router``, ``time_scale`` and ``busy_poll_us`` are ``RM``'s,
    except that ``time_scale`` defaults to 0 (unpaced): a vector client is there for
    throughput; ``no_graphics``, as in ``RM``, changes nothing (servers are headless).
    """

    def __init__(
        self,
        seed: int = 1234,
        port: int | Sequence[int] | None = None,
        num_envs: int = 1,
        *,
        servers: int = 1,
        no_graphics: bool = True,
        time_scale: float = 0.0,
        host: str = "127.0.0.1",
        launch: bool = True,
        timeout: float = 10.0,
        router: str | None = None,
        busy_poll_us: float = 0.0,
        **options: Any,
    ) -> None:
        check_launch(time_scale, busy_poll_us, seed=seed)
        ports = ports_of(port)
        count = len(ports) if ports is not None else servers
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise InvalidOptionError(f"num_envs must be a positive integer, got {num_envs!r}")
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= num_envs:
            raise InvalidOptionError(
                f"servers must be an integer in [1, num_envs={num_envs}], got {count!r}"
            )
        self.num_envs, self.seed, self.options = num_envs, int(seed), dict(options)
        self.shares = shares_of(num_envs, count)
        if max(self.shares) > MAX_ARENAS:
            need = math.ceil(num_envs / MAX_ARENAS)
            raise InvalidOptionError(
                f"{num_envs} arenas on {count} server(s) puts more than {MAX_ARENAS} on one "
                f"server; use at least {need} servers"
            )
        self.offsets = [sum(self.shares[:j]) for j in range(count)]
        self._conns: list[Connection] = []
        self._cache: dict[str, np.ndarray] = {}
        self._started = False
        try:
            for j in range(count):
                self._conns.append(
                    self._connect(j, None if ports is None else ports[j], host, launch,
                                  timeout, router, time_scale, busy_poll_us)
                )  # fmt: skip
            info = self._conns[0].call(VGet(what="env_info")).value
            self._info: dict[str, Any] = {**info, "num_envs": num_envs}
            self._table: list[dict[str, Any]] | None = None
        except BaseException:
            self.close()
            raise
        self.ports = [conn.port for conn in self._conns]
        """The port of each server, in arena order."""

    def _connect(
        self,
        j: int,
        port: int | None,
        host: str,
        launch: bool,
        timeout: float,
        router: str | None,
        time_scale: float,
        busy_poll_us: float,
    ) -> Connection:
        seed, share = self.seed + self.offsets[j], self.shares[j]
        return Connection(
            port=port,
            command=lambda p: ServerCommand(
                p, seed, host, arenas=share, time_scale=time_scale, busy_poll_us=busy_poll_us
            ),
            configure=Configure(seed=seed, options=self.options, arenas=share),
            host=host,
            router=router,
            launch=launch,
            timeout=timeout,
        )

    # ---- VecArenaAPI ---------------------------------------------------------------------

    def reset(
        self,
        contexts: Mapping[str, Any] | Sequence[Mapping[str, Any] | None] | None = None,
        seed: Any = None,
    ) -> np.ndarray:
        seeds = self._seeds(seed)
        if contexts is None or isinstance(contexts, Mapping):
            per_server: list[Any] = [None if contexts is None else dict(contexts)] * len(
                self._conns
            )
            self._check_contexts([contexts])
        else:
            per_arena = self._entries("contexts", contexts, InvalidContextError)
            self._check_contexts(per_arena)
            per_server = self._split([None if c is None else dict(c) for c in per_arena])
        seed_parts = self._split(seeds) if seeds is not None else [None] * len(self._conns)
        calls = [
            conn.send(VReset(contexts=c, seeds=s), InvalidContextError)
            for conn, c, s in zip(self._conns, per_server, seed_parts, strict=True)
        ]
        self._gather(calls)
        self._started = True
        return self._obs_copy()

    def step(
        self,
        actions: Any,
        *,
        seeds: Sequence[int | None] | None = None,
        contexts: Sequence[Mapping[str, Any] | None] | None = None,
        active: Sequence[bool] | np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        return self.step_async(actions, seeds=seeds, contexts=contexts, active=active).result()

    def step_async(
        self,
        actions: Any,
        *,
        seeds: Sequence[int | None] | None = None,
        contexts: Sequence[Mapping[str, Any] | None] | None = None,
        active: Sequence[bool] | np.ndarray | None = None,
    ) -> StepHandle:
        if not self._started:
            raise ResetNeededError("step() called before reset(): call reset() first")
        rows = self._rows(actions)
        seed_list = None if seeds is None else self._entries("seeds", seeds, InvalidContextError)
        if seed_list is not None:
            self._check_seeds(seed_list)
        ctx_list = None
        if contexts is not None:
            ctx_list = [None if c is None else dict(c) for c in self._entries(
                "contexts", contexts, InvalidContextError)]  # fmt: skip
            self._check_contexts(ctx_list)
        flags = None if active is None else self._flags(active)
        n = len(self._conns)
        calls: list[Call | dict[str, Any]] = [
            self._idle_reply(j)
            if f is not None and not any(f)
            else conn.send(
                VStep(
                    actions=part,
                    seeds=None if seed_list is None else s,
                    contexts=None if ctx_list is None else c,
                    active=None if flags is None else f,
                ),
                InvalidActionError,
            )
            for j, (conn, part, s, c, f) in enumerate(zip(
                self._conns,
                self._split(rows),
                self._split(seed_list) if seed_list is not None else [None] * n,
                self._split(ctx_list) if ctx_list is not None else [None] * n,
                self._split(flags) if flags is not None else [None] * n,
                strict=True,
            ))
        ]  # fmt: skip
        return _PendingStep(self, calls)

    def get_obs(self) -> np.ndarray:
        return self._read("obs")

    def get_state(self) -> np.ndarray:
        return self._read("state")

    def get_avail_actions(self) -> np.ndarray:
        return self._read("avail_actions")

    def get_env_info(self) -> dict[str, Any]:
        return dict(self._info)

    def close(self) -> None:
        self._cache = {}  # no answers from a closed client: every read says it is closed
        for conn in self._conns:
            conn.close()

    def __enter__(self) -> VecRM:
        return self

    # ---- requests ------------------------------------------------------------------------

    def _gather(self, calls: Sequence[Call | dict[str, Any]]) -> list[dict[str, Any]]:
        """Wait for every server's reply and keep the stacked arrays they carry."""
        values = [c if isinstance(c, dict) else c.result().value for c in calls]
        self._cache = {k: _stacked(values, k) for k in STACKED}
        return values

    def _idle_reply(self, j: int) -> dict[str, Any]:
        """What server ``j`` would reply to a step in which none of its arenas is active:
        its arenas as they are, no reward, not done, empty infos. Such a step is not sent,
        so with one server per group of arenas (``RolloutWorker``'s groups) a group's step
        reaches only its own server."""
        lo, k = self.offsets[j], self.shares[j]
        part = {name: self._cache[name][lo : lo + k].copy() for name in STACKED}
        n = int(self._info["n_agents"])
        return {**part, "rewards": np.zeros((k, n)), "dones": np.zeros(k, dtype=bool),
                "infos": [{} for _ in range(k)]}  # fmt: skip

    def _obs_copy(self) -> np.ndarray:
        return self._cache["obs"].copy()

    def _read(self, what: str) -> np.ndarray:
        if what in self._cache:
            return self._cache[what].copy()
        replies: list[OkReply] = [
            c.result() for c in (x.send(VGet(what=what)) for x in self._conns)
        ]
        return np.concatenate([r.value for r in replies])

    def _split(self, values: Any) -> list[Any]:
        """One part per server, in arena order (array slices stay arrays)."""
        return [values[o : o + k] for o, k in zip(self.offsets, self.shares, strict=True)]

    # ---- checks (what any server would refuse, refused before anything is sent) --------------

    def _entries(self, name: str, values: Any, error: type[Exception]) -> list[Any]:
        return per_arena(name, values, self.num_envs, error)

    def _seeds(self, seed: Any) -> list[int | None] | None:
        if seed is None:
            return None
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            seeds: list[int | None] = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = self._entries("seed", seed, InvalidContextError)
        self._check_seeds(seeds)
        return [None if s is None else int(s) for s in seeds]

    def _check_seeds(self, seeds: Sequence[Any]) -> None:
        for i, s in enumerate(seeds):
            if s is None:
                continue
            ok = isinstance(s, (int, np.integer)) and not isinstance(s, (bool, np.bool_))
            if not ok or not 0 <= int(s) <= MAX_SEED:
                raise InvalidContextError(
                    f"arena {i}: seed must be an integer in [0, {MAX_SEED}], got {s!r}"
                )

    def _rows(self, actions: Any) -> Any:
        if isinstance(actions, np.ndarray):
            if actions.ndim < 1 or len(actions) != self.num_envs:
                raise InvalidActionError(
                    f"actions must have {self.num_envs} rows (one per arena), got shape "
                    f"{actions.shape}"
                )
            rows = actions
        else:
            rows = self._entries("actions", actions, InvalidActionError)
        if len(self._conns) > 1:
            check_action_rows(rows, self._info, bool(self.options.get("clip_actions")))
        return rows

    def _flags(self, active: Sequence[bool] | np.ndarray) -> list[bool]:
        flags = np.asarray(active)
        if flags.shape != (self.num_envs,) or flags.dtype != np.bool_:
            raise InvalidActionError(
                f"active must hold {self.num_envs} booleans (one per arena), got {active!r:.80}"
            )
        return flags.tolist()

    def _check_contexts(self, per_arena: Sequence[Mapping[str, Any] | None]) -> None:
        if len(self._conns) == 1:
            return  # one server checks its whole request itself
        if self._table is None:
            self._table = self._conns[0].call(Contexts()).value
        for i, contexts in enumerate(per_arena):
            if contexts:
                check_contexts(contexts, self._table, f"arena {i}: ")


class _PendingStep(StepHandle):
    """A ``vstep`` sent to every server; :meth:`result` gathers and stacks the replies."""

    def __init__(self, vec: VecRM, calls: list[Call | dict[str, Any]]) -> None:
        super().__init__(None)
        self._vec, self._calls = vec, calls

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        if self._calls:  # the first call gathers the replies; later ones repeat them
            values = self._vec._gather(self._calls)
            rewards, dones = _stacked(values, "rewards"), _stacked(values, "dones")
            infos = [info for v in values for info in v["infos"]]
            self._value, self._calls = (self._vec._obs_copy(), rewards, dones, infos), []
        return self._value


def _stacked(values: list[dict[str, Any]], key: str) -> np.ndarray:
    """The servers' arrays under ``key`` in arena order (one server's array as it came: a
    decoded array is this client's own)."""
    return values[0][key] if len(values) == 1 else np.concatenate([v[key] for v in values])


def check_action_rows(rows: Any, info: Mapping[str, Any], clip: bool = False) -> None:
    """Refuse what an arena would refuse: wrong counts, non-integers and out-of-range indices
    (abstract, discrete), or non-finite and out-of-bound motions (continuous, unless the
    arenas clip). ``InvalidActionError`` names the arena and agent."""
    n_agents, n_actions = int(info["n_agents"]), int(info["n_actions"])
    continuous = info["action_space"] == "continuous"
    if (
        not continuous
        and isinstance(rows, np.ndarray)
        and rows.dtype.kind in "iu"
        and rows.shape == (len(rows), n_agents)
        and not ((rows < 0) | (rows >= n_actions)).any()
    ):
        return  # every row valid, checked at once (a sampler's step); else find the culprit
    for i, row in enumerate(rows):
        try:
            arr = np.asarray(row, dtype=np.float64)
        except (TypeError, ValueError):
            raise InvalidActionError(
                f"arena {i}: actions must be numbers, got {row!r:.80}"
            ) from None
        want = (n_agents, 4) if continuous else (n_agents,)
        if arr.shape != want:
            raise InvalidActionError(
                f"arena {i}: expected actions of shape {want} (one per agent), got {arr.shape}"
            )
        targets = arr[:, 3] if continuous else arr
        bad = ~(np.isfinite(targets) & (targets == np.round(targets)))
        bad |= (targets < 0) | (targets >= n_actions)
        if continuous and not clip:
            bound = MOTION_HIGH.astype(np.float64)
            bad |= ~np.isfinite(arr[:, :3]).all(axis=1) | (np.abs(arr[:, :3]) > bound).any(axis=1)
        if bad.any():
            agent = int(np.flatnonzero(bad)[0])
            raise InvalidActionError(
                f"arena {i}: agent {agent}: action {np.asarray(row)[agent].tolist()!r} is out of "
                "range; valid: "
                + ("(vx, vy, omega within bounds, target in [0, "
                   f"{n_actions - 1}])" if continuous else f"[0, {n_actions - 1}]")
            )  # fmt: skip


def check_contexts(contexts: Mapping[str, Any], table: list[dict[str, Any]], where: str) -> None:
    """Refuse what a server would refuse, from its context table: unknown keys, values out
    of range, level values not among its choices."""
    rows = {row["key"]: row for row in table}
    for key, value in contexts.items():
        row = rows.get(key)
        if row is None:
            raise InvalidContextError(f"{where}unknown context key {key!r}; valid: {sorted(rows)}")
        if "choices" in row:
            if isinstance(value, bool) or value not in row["choices"]:
                raise InvalidContextError(
                    f"{where}context {key!r}={value!r} is not valid; choose one of {row['choices']}"
                )
            continue
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not number or not math.isfinite(value) or not row["min"] <= value <= row["max"]:
            raise InvalidContextError(
                f"{where}context {key!r}={value!r} is out of range; valid: "
                f"[{row['min']}, {row['max']}]"
            )
