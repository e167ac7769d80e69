"""The arena service: request bytes in, reply bytes out, whatever the bytes are.

This is the transport-free half of the server (``server/serving/rpc.py`` is the Zenoh half), so the
rules below can be tested without a network:

* Every request gets a reply. Undecodable, mistyped or oversized requests get a typed error
  reply; they never reach the arena, so the episode in progress is untouched.
* One server holds ``arenas`` arenas (a :class:`~neuronsmae.server.vec.VecArena`; one by
  default), owned together by at most one client session at a time. ``configure`` claims
  them; the owner keeps them until it sends ``close`` or stays silent for ``lease_s``
  seconds, and while it holds them every other session's ``configure`` (and arena request)
  gets ``BusyError``. Ping and the context table are answered for anyone.
* ``configure`` rebuilds the arenas when their (seed, options) differ from the current ones,
  or when they have run episodes for another session: so ``RM(seed=s)`` replays exactly
  what ``Arena(seed=s)`` would, however the server was used before.
* The one-arena messages (``reset``, ``step``, ``get``, ``render``) serve a one-arena
  server and answer as ``Arena`` does in process (errors without an arena index); the
  vector messages (``vreset``, ``vstep``, ``vget``) serve any and name the arena in their
  errors (``arena 0`` of one). Every change of state goes through the ``VecArena``, so the
  two kinds may be mixed on a one-arena server: they play the same episode, and an episode
  that ends at either is over for both (``step`` then needs a reset; ``vstep`` autoresets).
* A reply speaks the request's protocol version (``reply_in_version``).
* ``step`` and ``vstep`` are paced to at most ``time_scale`` times real time (0 = unlimited).
"""

from __future__ import annotations

import ctypes
import gc
import logging
import os
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuronsmae.protocol.codec import encode
from neuronsmae.protocol.defaults import DEFAULT_SEED, UNPACED
from neuronsmae.protocol.errors import (
    BusyError,
    InvalidOptionError,
    MalformedMessageError,
    NeuronsMAEError,
    ServerError,
)
from neuronsmae.protocol.interface import ArenaAPI, check_seeds
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
    VGet,
    VReset,
    VStep,
    decode_request,
    encode_reply,
    max_first_seed,
    reply_in_version,
)
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.vec import VecArena, as_the_arena

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
    """The current arenas and what they were built from."""

    vec: VecArena
    seed: int
    options: dict[str, Any]
    session: str | None = None
    used: bool = False


SNAPSHOT_AFTER: frozenset[type[Message]] = frozenset({Reset, Step})
"""Requests whose replies carry the state and availability masks (see ``OkReply``)."""
ONE_ARENA: frozenset[type[Message]] = frozenset({Reset, Step, Get, Render})
"""Requests that address the one arena of a one-arena server."""


def one_arena_only(kind: str, arenas: int) -> str:
    """The refusal of a one-arena request ``kind`` by a server of ``arenas`` arenas, naming
    what works instead: the vector message, or for ``render`` (which has none) a one-arena
    server."""
    if kind == Render.TYPE:
        return (
            f"'render' addresses a one-arena server; this one holds {arenas} arenas and "
            "there is no vector render: render from a server started with --arenas 1 (RM), "
            "or in process (VecArena.arenas[i].render())"
        )
    return (
        f"{kind!r} addresses a one-arena server; this one holds {arenas} arenas: send "
        f"'v{kind}' with one entry per arena"
    )


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
    """A canonical form of options for comparing configurations: every option with its
    default filled in, so ``{}`` and ``{"action_space": "abstract"}`` are the same task
    (an invalid option raises :class:`InvalidOptionError` here, before anything changes)."""
    return encode(sorted(ArenaConfig.from_options(options).to_dict().items()))


class ArenaService:
    """Decodes requests, enforces ownership, calls the arena and encodes replies."""

    def __init__(
        self,
        factory: Callable[..., ArenaAPI],
        seed: int = DEFAULT_SEED,
        time_scale: float = UNPACED,
        lease_s: float = DEFAULT_LEASE_S,
        context_table: Callable[[], Any] | None = None,
        clock: Callable[[], float] = time.monotonic,
        arenas: int = 1,
    ) -> None:
        self.server_id = uuid.uuid4().hex
        """Identifies this server process; a client sees it change when a server restarts."""
        self.arenas = arenas
        """How many arenas this server holds (``neuronsmae-server --arenas``)."""
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
            VReset: self._vreset,
            VStep: self._vstep,
            VGet: self._vget,
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
            built.vec.close()

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
        if type(body) in ONE_ARENA and self.arenas != 1:
            raise MalformedMessageError(one_arena_only(body.TYPE, self.arenas))
        value = self._handlers[type(body)](body, request.session)
        return reply_in_version(type(body), value, request.version)

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
        vec = self._vec
        return {"state": vec.get_state()[0], "avail_actions": list(vec.get_avail_actions()[0])}

    @property
    def _vec(self) -> VecArena:
        if self._built is None:
            raise ServerError("the server has no arena (it is shutting down)")
        return self._built.vec

    @property
    def _arena(self) -> ArenaAPI:
        """The arena of a one-arena server, for reads (changes go through ``_vec``)."""
        return self._vec.arenas[0]

    # ---- handlers ----------------------------------------------------------------------

    def _configure(self, body: Configure, session: str) -> dict[str, Any]:
        now = self._clock()
        if self._owner not in (None, session) and now - self._owner_seen < self._lease_s:
            raise self._busy()
        wanted = 1 if body.arenas is None else body.arenas
        if wanted != self.arenas:
            raise InvalidOptionError(
                f"this server holds {self.arenas} arena(s) (neuronsmae-server --arenas "
                f"{self.arenas}); the client asked for {wanted}: use a client for "
                f"{self.arenas} arena(s) (RM for one, VecRM(num_envs={self.arenas}) for more) "
                "or a server started with the count it needs"
            )
        seed = self._default_seed if body.seed is None else body.seed
        if seed > max_first_seed(self.arenas):
            raise InvalidOptionError(
                f"seed {seed} is out of range for {self.arenas} arenas (arena i is seeded "
                f"seed + i); valid: [0, {max_first_seed(self.arenas)}]"
            )
        key = _options_key(body.options)
        built = self._built
        rebuilt = (
            built is None
            or (built.seed, _options_key(built.options)) != (seed, key)
            or (built.used and built.session != session)
        )
        if rebuilt:
            self._build(seed, body.options)
        assert self._built is not None
        self._built.session = session
        self._owner, self._owner_seen = session, now
        return {
            "version": PROTOCOL_VERSION,
            "server": self.server_id,
            "rebuilt": rebuilt,
            "arenas": self.arenas,
        }

    def _build(self, seed: int, options: dict[str, Any]) -> None:
        """Replace the arenas, holding one set in memory at a time.

        The options are checked first, so a refused option leaves the old arenas serving
        their episodes. The old arenas are then freed before the new ones are built: built
        beside them, a K-arena server would hold both sets at once, and the C allocator
        keeps such a peak (a K = 8 server stayed 300 MB larger after one rebuild). Should the
        build fail even so, the old arenas are built again from their seed and options (their
        episodes are lost) and the error is raised.
        """
        ArenaConfig.from_options(options)
        old, self._built = self._built, None
        previous = None if old is None else (old.seed, old.options)
        if old is not None:
            old.vec.close()
            del old
            _release_memory()
        try:
            vec = VecArena(seed, self.arenas, factory=self._factory, **options)
        except BaseException:
            if previous is not None:
                seed_was, options_were = previous
                again = VecArena(seed_was, self.arenas, factory=self._factory, **options_were)
                self._built = _Built(again, seed_was, options_were)
            raise
        self._built = _Built(vec, seed, dict(options))
        period = 0.0
        if self._time_scale > 0:
            steps = vec.get_env_info().get("decision_steps", 1)
            period = steps * PHYSICS_DT / self._time_scale
        self._pacer = Pacer(period, clock=self._clock)
        log.info("arena built: seed=%s options=%s", seed, options)

    def _reset(self, body: Reset, session: str) -> Any:
        assert self._built is not None
        self._built.used = True
        with as_the_arena():
            self._vec.reset(body.contexts, None if body.seed is None else [body.seed])
        return self._arena.get_obs()

    def _step(self, body: Step, session: str) -> Any:
        arena, vec = self._arena, self._vec
        if arena.done:  # one-arena semantics: no autoreset
            arena.step(body.actions)  # raises ResetNeededError, exactly as in process
        self._pacer.wait()
        with as_the_arena():
            _, rewards, dones, infos = vec.step([body.actions])
        return [arena.get_obs(), rewards[0].tolist(), bool(dones[0]), infos[0]]

    def _get(self, body: Get, session: str) -> Any:
        return getattr(self._arena, f"get_{body.what}")()

    def _vreset(self, body: VReset, session: str) -> Any:
        assert self._built is not None
        self._built.used = True
        vec = self._vec
        if body.seeds is not None:  # named as the wire field, not as VecArena's argument
            check_seeds(body.seeds, vec.num_envs, "seeds")
        vec.reset(body.contexts, body.seeds)
        return self._arrays(vec)

    def _vstep(self, body: VStep, session: str) -> Any:
        vec = self._vec
        self._pacer.wait()
        actions = body.actions
        obs, rewards, dones, infos = vec.step(
            actions, seeds=body.seeds, contexts=body.contexts, active=body.active
        )
        return {**self._arrays(vec, obs), "rewards": rewards, "dones": dones, "infos": infos}

    def _vget(self, body: VGet, session: str) -> Any:
        return getattr(self._vec, f"get_{body.what}")()

    @staticmethod
    def _arrays(vec: VecArena, obs: np.ndarray | None = None) -> dict[str, np.ndarray]:
        """What a vector reply always carries: observations, states and masks."""
        return {
            "obs": vec.get_obs() if obs is None else obs,
            "state": vec.get_state(),
            "avail_actions": vec.get_avail_actions(),
        }

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
            "arenas": self.arenas,
            "pid": os.getpid(),
        }

    def _close(self, body: Close, session: str) -> None:
        if self._owner == session:
            self._owner = None


def _release_memory() -> None:
    """Collect cycles and hand freed heap pages back to the system (glibc's
    ``malloc_trim``; elsewhere only the collection)."""
    gc.collect()
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (AttributeError, OSError, TypeError):  # no glibc; Windows refuses CDLL(None)
        return
    trim(0)
