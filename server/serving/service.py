"""The arena service: request bytes in, reply bytes out, whatever the bytes are.

This is the transport-free half of the server (``server/serving/rpc.py`` is the Zenoh half), so the
rules below can be tested without a network:

* Every request gets a reply. Undecodable, mistyped or oversized requests get a typed error
  reply; they never reach the arena, so the episode in progress is untouched.
* One arena per process, owned by at most one client session at a time. ``configure`` claims
  it; the owner keeps it until it sends ``close`` or stays silent for ``lease_s`` seconds, and
  while it holds it every other session's ``configure`` (and arena request) gets
  ``BusyError``. Ping and the context table are answered for anyone.
* ``configure`` rebuilds the arena when its (seed, options) differ from the current ones, or
  when the arena has run episodes for another session: so ``RM(seed=s)`` replays exactly what
  ``Arena(seed=s)`` would, however the server was used before.
* ``step`` is paced to at most ``time_scale`` times real time (0 = unlimited).
"""

from __future__ import annotations

import logging
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from neuronsmae.protocol.codec import encode
from neuronsmae.protocol.errors import BusyError, NeuronsMAEError, ServerError
from neuronsmae.protocol.interface import ArenaAPI
from neuronsmae.protocol.messages import (
    PROTOCOL_VERSION,
    Close,
    Configure,
    Contexts,
    ErrorReply,
    Get,
    Message,
    NotConfiguredError,
    OkReply,
    Ping,
    Render,
    Reply,
    Request,
    Reset,
    Step,
    decode_request,
    encode_reply,
)

log = logging.getLogger("neuronsmae.server")

PHYSICS_DT = 0.02
"""Simulated seconds per physics step; a decision lasts ``decision_steps`` of them."""
DEFAULT_LEASE_S = 60.0
WARM_UP_OPTIONS: dict[str, Any] = {"lidar": True, "observability": "partial"}
"""Options whose first decision compiles nearly every kernel of the simulation."""


class Pacer:
    """Keeps calls at least ``period`` seconds apart on average (never bursting to catch up).

    Why not sleep a fixed amount: the step itself takes time, and only the remainder of
    the period should be waited for.
    """

    def __init__(
        self,
        period: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.period = period
        self._clock, self._sleep = clock, sleep
        self._next = 0.0

    def wait(self) -> None:
        if self.period <= 0.0:
            return
        now = self._clock()
        if now < self._next:
            self._sleep(self._next - now)
            now = self._next
        self._next = now + self.period


@dataclass
class _Built:
    """The current arena and what it was built from."""

    arena: ArenaAPI
    seed: int
    options_key: bytes
    session: str | None = None
    used: bool = False


SNAPSHOT_AFTER: frozenset[type[Message]] = frozenset({Reset, Step})
"""Requests whose replies carry the state and availability masks (see ``OkReply``)."""


def warm_up(factory: Callable[..., ArenaAPI], seed: int = 0) -> None:
    """Play one decision on a throwaway arena with the costliest options.

    The simulation's numba kernels compile on first use (tens of seconds with a cold
    cache): paying that before serving keeps a client's first ``step`` within its timeout.
    A throwaway arena, so the served one stays exactly as freshly built.
    """
    try:
        arena = factory(seed=seed, **WARM_UP_OPTIONS)
    except NeuronsMAEError as exc:  # an arena without these options: nothing to warm
        log.info("warm-up skipped: %s", exc)
        return
    try:
        arena.reset()
        arena.step([0] * arena.get_env_info()["n_agents"])
    except Exception:  # report, but let clients see the failure on their own requests
        log.exception("warm-up episode failed")
    finally:
        arena.close()


def _options_key(options: dict[str, Any]) -> bytes:
    """A canonical form of options for comparing configurations exactly."""
    return encode(sorted(options.items()))


class ArenaService:
    """Decodes requests, enforces ownership, calls the arena and encodes replies."""

    def __init__(
        self,
        factory: Callable[..., ArenaAPI],
        seed: int = 1234,
        time_scale: float = 0.0,
        lease_s: float = DEFAULT_LEASE_S,
        context_table: Callable[[], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.server_id = uuid.uuid4().hex
        """Identifies this server process; a client sees it change when a server restarts."""
        self._factory = factory
        self._default_seed = seed
        self._time_scale = time_scale
        self._lease_s = lease_s
        self._context_table = context_table
        self._clock = clock
        self._built: _Built | None = None
        self._owner: str | None = None
        self._owner_seen = 0.0
        self._pacer = Pacer(clock=clock)
        self._handlers: dict[type[Message], Callable[[Any, str], Any]] = {
            Configure: self._configure,
            Reset: self._reset,
            Step: self._step,
            Get: self._get,
            Render: lambda body, session: self._arena.render(),
            Contexts: self._contexts,
            Ping: self._ping,
            Close: self._close,
        }
        self._open_to_all: frozenset[type[Message]] = frozenset({Configure, Contexts, Ping, Close})

    # ---- lifecycle ---------------------------------------------------------------------

    def __enter__(self) -> ArenaService:
        """Warm up, then build the default arena, all before the first request is served."""
        warm_up(self._factory, self._default_seed)
        self._build(self._default_seed, {})
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Close the arena; safe to call twice."""
        built, self._built = self._built, None
        if built is not None:
            built.arena.close()

    # ---- the one entry point -----------------------------------------------------------

    def handle(self, data: bytes) -> bytes:
        """Answer one request. Never raises: every failure becomes an error reply."""
        reply: Reply
        try:
            request = decode_request(data)
            value = self._dispatch(request)
            snapshot = self._snapshot() if type(request.body) in SNAPSHOT_AFTER else None
            reply = OkReply(value, snapshot)
        except NeuronsMAEError as exc:
            log.debug("request refused: %s: %s", exc.code, exc)
            reply = ErrorReply.from_exception(exc)
        except Exception as exc:  # the arena failed: report it, keep serving
            log.exception("request failed")
            reply = ErrorReply(ServerError.code, f"{type(exc).__name__}: {exc}")
        try:
            return encode_reply(reply)
        except NeuronsMAEError as exc:
            log.error("cannot encode reply: %s", exc)
            return encode_reply(ErrorReply(ServerError.code, f"cannot encode reply: {exc}"))

    def _dispatch(self, request: Request) -> Any:
        body = request.body
        if type(body) not in self._open_to_all:
            self._check_owner(request.session)
        return self._handlers[type(body)](body, request.session)

    def _check_owner(self, session: str) -> None:
        if self._owner is None:
            raise NotConfiguredError(
                "send 'configure' first (no client owns this server; it may have restarted)"
            )
        if session != self._owner:
            raise self._busy()
        self._owner_seen = self._clock()

    def _busy(self) -> BusyError:
        idle = self._clock() - self._owner_seen
        return BusyError(
            f"this server's arena is owned by another client (idle {idle:.1f} s); it is "
            f"released when that client closes or after {self._lease_s:g} s of silence"
        )

    def _snapshot(self) -> dict[str, Any]:
        arena = self._arena
        return {"state": arena.get_state(), "avail_actions": arena.get_avail_actions()}

    @property
    def _arena(self) -> ArenaAPI:
        if self._built is None:
            raise ServerError("the server has no arena (it is shutting down)")
        return self._built.arena

    # ---- handlers ----------------------------------------------------------------------

    def _configure(self, body: Configure, session: str) -> dict[str, Any]:
        now = self._clock()
        if self._owner not in (None, session) and now - self._owner_seen < self._lease_s:
            raise self._busy()
        seed = self._default_seed if body.seed is None else body.seed
        key = _options_key(body.options)
        built = self._built
        rebuilt = (
            built is None
            or (built.seed, built.options_key) != (seed, key)
            or (built.used and built.session != session)
        )
        if rebuilt:
            self._build(seed, body.options)
        assert self._built is not None
        self._built.session = session
        self._owner, self._owner_seen = session, now
        return {"version": PROTOCOL_VERSION, "server": self.server_id, "rebuilt": rebuilt}

    def _build(self, seed: int, options: dict[str, Any]) -> None:
        """Build the new arena first, so a refused option leaves the old one serving."""
        arena = self._factory(seed=seed, **options)
        old, self._built = self._built, _Built(arena, seed, _options_key(options))
        if old is not None:
            old.arena.close()
        period = 0.0
        if self._time_scale > 0:
            steps = arena.get_env_info().get("decision_steps", 1)
            period = steps * PHYSICS_DT / self._time_scale
        self._pacer = Pacer(period, clock=self._clock)
        log.info("arena built: seed=%s options=%s", seed, options)

    def _reset(self, body: Reset, session: str) -> Any:
        assert self._built is not None
        self._built.used = True
        return self._arena.reset(contexts=body.contexts, seed=body.seed)

    def _step(self, body: Step, session: str) -> Any:
        arena = self._arena
        self._pacer.wait()
        return list(arena.step(body.actions))

    def _get(self, body: Get, session: str) -> Any:
        return getattr(self._arena, f"get_{body.what}")()

    def _contexts(self, body: Contexts, session: str) -> Any:
        if self._context_table is None:
            raise ServerError("this server has no context table")
        return self._context_table()

    def _ping(self, body: Ping, session: str) -> dict[str, Any]:
        return {
            "version": PROTOCOL_VERSION,
            "server": self.server_id,
            "owned": self._owner is not None,
            "time_scale": self._time_scale,
        }

    def _close(self, body: Close, session: str) -> None:
        if self._owner == session:
            self._owner = None
