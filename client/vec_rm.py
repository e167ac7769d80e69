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
from neuronsmae.protocol.actions import check_joint, used_agents
from neuronsmae.protocol.defaults import DEFAULT_HOST, DEFAULT_SEED, UNPACED
from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    ResetNeededError,
)
from neuronsmae.protocol.interface import (
    StepHandle,
    VecArenaAPI,
    check_seeds,
    count_option,
    first_seed,
    inherit_docstrings,
    per_arena,
    plain_contexts,
    seeds_per_arena,
    shares_of,
)
from neuronsmae.protocol.launch import ServerCommand, check_launch, ports_of
from neuronsmae.protocol.messages import (
    MAX_ARENAS,
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
    throughput; ``no_graphics``, as in ``RM``, changes nothing (a 3-D window
    opens only with the ``gui`` option).
    ``seed`` must be an integer: unlike ``RM(seed=None)``, which keeps a server's own
    ``--seed``, a vector seeds arena i ``seed + i`` across its servers, which servers' own
    seeds cannot give (``InvalidOptionError``, as ``VecArena(seed=None)``).

    ``step`` checks the rows of the arenas that step in the call only, whatever the number
    of servers: an inactive or autoresetting arena's row is ignored, and so are the actions
    of a bot-driven team (``bot_team``); every ``seeds`` and ``contexts`` entry is checked.
    Over several servers the checks run here before anything is sent, so this client
    remembers which arenas have ended their episodes (gathering a step still in flight
    that touches an arena of the new step first).
    """

    def __init__(
        self,
        seed: int = DEFAULT_SEED,
        port: int | Sequence[int] | None = None,
        num_envs: int = 1,
        *,
        servers: int = 1,
        no_graphics: bool = True,
        time_scale: float = UNPACED,
        host: str = DEFAULT_HOST,
        launch: bool = True,
        timeout: float = 10.0,
        router: str | None = None,
        busy_poll_us: float = 0.0,
        **options: Any,
    ) -> None:
        check_launch(time_scale, busy_poll_us)
        ports = ports_of(port)
        count = len(ports) if ports is not None else servers
        num_envs = count_option("num_envs", num_envs, 1)
        count = count_option("servers", count, 1, num_envs)
        self.num_envs, self.seed, self.options = num_envs, first_seed(seed, num_envs), dict(options)
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
        # What a request to several servers is checked against (see ``_stepping``):
        self._done = np.ones(num_envs, dtype=bool)
        """Whose episode ended at its last gathered step: the next step resets it."""
        self._contexts: list[dict[str, Any] | None] = [None] * num_envs
        """The contexts each arena was last reset with (its ``bot_team`` says whose
        actions it ignores)."""
        self._pending: list[_PendingStep] = []
        """Steps sent to several servers whose replies are not gathered yet."""
        self._epoch = 0
        """Counts resets: a step sent before the last reset no longer says who is done."""
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
            one = plain_contexts(contexts)
            per_arena = [one] * self.num_envs
            per_server: list[Any] = [one] * len(self._conns)
        else:
            entries = self._entries("contexts", contexts, InvalidContextError)
            per_arena = [plain_contexts(c, f"arena {i}: ") for i, c in enumerate(entries)]
            per_server = self._split(per_arena)
        self._check_contexts(per_arena)
        seed_parts = self._split(seeds) if seeds is not None else [None] * len(self._conns)
        calls = [
            conn.send(VReset(contexts=c, seeds=s), InvalidContextError)
            for conn, c, s in zip(self._conns, per_server, seed_parts, strict=True)
        ]
        self._gather(calls)
        self._started = True
        self._epoch += 1
        self._pending = []
        self._done[:] = False
        self._contexts = list(per_arena)
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
        seed_list = None if seeds is None else check_seeds(seeds, self.num_envs)
        ctx_list = None
        if contexts is not None:
            ctx_list = [
                plain_contexts(c, f"arena {i}: ")
                for i, c in enumerate(self._entries("contexts", contexts, InvalidContextError))
            ]
            self._check_contexts(ctx_list)
        flags = None if active is None else self._flags(active)
        on = np.ones(self.num_envs, dtype=bool) if flags is None else np.array(flags)
        if len(self._conns) > 1:
            self._check_rows(rows, on, ctx_list)
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
        handle = _PendingStep(self, calls, on)
        if len(self._conns) > 1:
            self._pending.append(handle)
        return handle

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
        seeds = seeds_per_arena(seed, self.num_envs)
        return None if all(s is None for s in seeds) else seeds

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
        return rows

    def _check_rows(
        self, rows: Any, on: np.ndarray, ctx_list: Sequence[dict[str, Any] | None] | None
    ) -> None:
        """Refuse, before anything is sent to several servers, a row that its server would
        refuse: the rows of the arenas that step in this call, without the actions of a
        team a bot drives (what the servers check; the other rows are ignored there)."""
        self._settle(on)
        resetting = on & self._done
        used: dict[int, list[bool] | None] = {}
        mode, agents = self._info.get("mode", ""), list(self._info.get("agents", []))
        for i in np.flatnonzero(on & ~self._done).tolist():
            bot_team = (self._contexts[i] or {}).get("bot_team", "none")
            used[i] = used_agents(agents, mode, bot_team)
        check_action_rows(rows, self._info, bool(self.options.get("clip_actions")), used)
        for i in np.flatnonzero(resetting).tolist():  # what these arenas reset with
            if ctx_list is not None and ctx_list[i]:
                self._contexts[i] = ctx_list[i]

    def _settle(self, on: np.ndarray) -> None:
        """Gather the steps in flight that touch arenas of ``on`` (and those sent before
        them, in order), so that whose episode has ended is known for every such arena."""
        last = max((n for n, h in enumerate(self._pending) if (h.on & on).any()), default=-1)
        for handle in list(self._pending[: last + 1]):
            handle.result()

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

    def __init__(self, vec: VecRM, calls: list[Call | dict[str, Any]], on: np.ndarray) -> None:
        super().__init__(None)
        self._vec, self._calls = vec, calls
        self.on = on
        """The arenas this step touches (its ``active``)."""
        self._epoch = vec._epoch
        self._error: BaseException | None = None

    def result(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
        if self._error is not None:
            raise self._error
        if self._calls:  # the first call gathers the replies; later ones repeat them
            vec = self._vec
            try:
                values = vec._gather(self._calls)
            except BaseException as exc:
                self._error, self._calls = exc, []
                self._forget()
                raise
            rewards, dones = _stacked(values, "rewards"), _stacked(values, "dones")
            infos = [info for v in values for info in v["infos"]]
            self._value, self._calls = (vec._obs_copy(), rewards, dones, infos), []
            if self._epoch == vec._epoch:
                vec._done[self.on] = dones[self.on]
            self._forget()
        return self._value

    def _forget(self) -> None:
        if self in self._vec._pending:
            self._vec._pending.remove(self)


def _stacked(values: list[dict[str, Any]], key: str) -> np.ndarray:
    """The servers' arrays under ``key`` in arena order (one server's array as it came: a
    decoded array is this client's own)."""
    return values[0][key] if len(values) == 1 else np.concatenate([v[key] for v in values])


def check_action_rows(
    rows: Any,
    info: Mapping[str, Any],
    clip: bool = False,
    used: Mapping[int, Sequence[bool] | None] | None = None,
) -> None:
    """Refuse what an arena would refuse (the shared
    :func:`~neuronsmae.protocol.actions.check_joint`): ``InvalidActionError`` names the
    arena and agent. ``used`` maps each arena whose row is checked to whose actions it uses
    (None: every agent's); None checks every row, all agents."""
    n_agents, n_actions = int(info["n_agents"]), int(info["n_actions"])
    space = str(info["action_space"])
    checked = range(len(rows)) if used is None else sorted(used)
    masks: Mapping[int, Sequence[bool] | None] = used or {}
    if (
        space != "continuous"
        and isinstance(rows, np.ndarray)
        and rows.dtype.kind in "iu"
        and rows.shape == (len(rows), n_agents)
    ):
        part = rows[list(checked)]
        if not ((part < 0) | (part >= n_actions)).any():
            return  # every row valid, checked at once (a sampler's step); else find the culprit
    n_enemy = int(info.get("n_enemies", n_actions))
    for i in checked:
        try:
            check_joint(rows[i], n_agents, space, n_actions, n_enemy, clip, masks.get(i))
        except InvalidActionError as exc:
            raise InvalidActionError(f"arena {i}: {exc}") from None


def check_contexts(contexts: Mapping[str, Any], table: list[dict[str, Any]], where: str) -> None:
    """Refuse what a server would refuse, from its context table: unknown keys, values out
    of range, level values not among its choices."""
    rows = {row["key"]: row for row in table}
    for key, value in contexts.items():
        row = rows.get(key)
        if row is None:
            raise InvalidContextError(
                f"{where}unknown context key {key!r:.80}; valid: {sorted(rows)}"
            )
        if "choices" in row:
            if isinstance(value, bool) or value not in row["choices"]:
                raise InvalidContextError(
                    f"{where}context {key!r}={value!r:.80} is not valid; "
                    f"choose one of {row['choices']}"
                )
            continue
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not number or not math.isfinite(value) or not row["min"] <= value <= row["max"]:
            raise InvalidContextError(
                f"{where}context {key!r}={value!r} is out of range; valid: "
                f"[{row['min']}, {row['max']}]"
            )
