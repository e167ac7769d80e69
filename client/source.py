"""Where a face's arena comes from, which keyword arguments it takes, and its first seed.

Every face (:class:`~neuronsmae.client.gym_env.CoopEnv`,
:class:`~neuronsmae.client.vec_env.CoopVectorEnv`,
:class:`~neuronsmae.client.agents_env.AgentsEnv`,
:class:`~neuronsmae.client.pz_env.ArenaParallelEnv`, :class:`~neuronsmae.client.smac.SMACEnv`)
takes ``env=`` one of:

* ``None`` (the default): a private server launched on a free loopback port, stopped when
  the face is closed, so any number of faces run side by side. Its keyword arguments are
  ``RM``'s (``port``, ``host``, ``timeout``, ``time_scale``, ...) and the arena options.
  Unlike a bare ``RM``, a face's server is **unpaced** (``time_scale=0``) unless
  ``time_scale`` is given: a face is there to be trained on. An explicit ``port`` connects
  to the server there, or launches one on it (``RM``'s connect-or-launch).
* a string ``"module:attr"`` naming an arena class or factory, called as
  ``attr(seed=seed, **options)``: ``"neuronsmae.server:Arena"`` (vector faces:
  ``"neuronsmae.server:VecArena"``, called with ``num_envs`` too) runs the arenas in this
  process, and ``"inprocess"`` is short for it (:data:`IN_PROCESS`). A string, because
  configuration files (EPyMARL's ``env_args``, YAML, the command line) cannot hold a Python
  object, and because the client never imports the server by itself: the server package is
  imported by name when such an arena is opened, which is how the trainers reach in-process
  arenas too (trainers → client → protocol ← server).
* an arena object (``ArenaAPI``, or ``VecArenaAPI`` for the vector face) or a zero-argument
  factory of one, built by the caller with its own options; no options may be given then.

Keyword arguments that fit none of these are refused with :class:`InvalidOptionError`
**before anything is launched**, naming the valid ones.

Seeding follows Gymnasium: the first ``reset`` without a seed draws one from the operating
system's entropy, so unseeded copies play different episodes, unless a seed was given to
the constructor (``seed=``, or to the arena the caller built), which then decides every
episode from the first one on.

A face pickles as its recipe (:class:`Recipe`, Gymnasium's ``EzPickle``): unpickling (or
``copy.deepcopy``) builds a new environment from the same arguments (its own private server
when served; the vector face its own vector servers), not a copy of the running episode.
That is how SuperSuit's ``concat_vec_envs_v1`` and others copy an environment. A face
wrapping an arena object cannot be copied so; a ``"module:attr"`` name or a factory can.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
from gymnasium.utils import EzPickle

from neuronsmae.client.spaces import Layout
from neuronsmae.client.viewer import check_render_mode
from neuronsmae.protocol.env_info import ARENA_OPTIONS
from neuronsmae.protocol.errors import ForkedZenohError, InvalidOptionError, NotCopyableError
from neuronsmae.protocol.interface import ArenaAPI, VecArenaAPI
from neuronsmae.protocol.link import check_fork_safe
from neuronsmae.protocol.messages import MAX_SEED

ArenaSource = ArenaAPI | Callable[[], ArenaAPI] | str | None
"""What a face wraps: an arena, a zero-argument factory of one, ``"module:attr"`` naming an
arena class, or None for a private served arena (see the module docstring)."""

RM_ARGUMENTS = frozenset(
    {"port", "no_graphics", "time_scale", "host", "launch", "timeout", "router", "busy_poll_us"}
)
"""``RM``'s own arguments (what server to reach or launch, and how)."""
VEC_RM_ARGUMENTS = RM_ARGUMENTS | {"servers"}
"""``VecRM``'s own arguments."""


def check_options(given: Iterable[str], valid: Iterable[str], where: str, hint: str = "") -> None:
    """Refuse keyword arguments outside ``valid``, naming them and listing the valid ones."""
    valid = set(valid)
    unknown = sorted(set(given) - valid)
    if unknown:
        raise InvalidOptionError(
            f"{where}: unknown option(s) {unknown}; valid options: {sorted(valid)}{hint}"
        )


IN_PROCESS = {"arena": "neuronsmae.server:Arena", "vector": "neuronsmae.server:VecArena"}
"""What ``env="inprocess"`` names: the server's arena classes, for one arena and for a
vector of them."""


def resolve(name: str, kind: str = "arena") -> Callable[..., Any]:
    """The object a ``"module:attr"`` string names (imported now); ``"inprocess"`` names
    the in-process arena of ``kind`` (``arena`` or ``vector``, :data:`IN_PROCESS`)."""
    if name == "inprocess":
        name = IN_PROCESS[kind]
    module, sep, attr = name.partition(":")
    if not sep or not module or not attr:
        raise InvalidOptionError(
            f"env={name!r} must name an arena class as 'module:attr', e.g. "
            "'neuronsmae.server:Arena', or be 'inprocess'"
        )
    try:
        target: Any = importlib.import_module(module)
        for part in attr.split("."):
            target = getattr(target, part)
    except (ImportError, AttributeError) as exc:
        raise InvalidOptionError(f"env={name!r} names nothing importable: {exc}") from exc
    if not callable(target):
        raise InvalidOptionError(f"env={name!r} names {target!r}, which cannot be called")
    return target  # type: ignore[no-any-return]


def open_arena(
    env: ArenaSource,
    seed: int | None,
    kwargs: Mapping[str, Any],
    where: str,
) -> tuple[ArenaAPI, bool]:
    """The arena a face will own, and whether its first episode is seeded by construction.

    See the module docstring for what ``env`` may be; ``kwargs`` are the face's leftover
    keyword arguments (``RM``'s and the arena options). The remote client is imported only
    here and only when asked for, so wrapping an in-process arena never touches Zenoh.
    """
    if env is None or isinstance(env, str):
        served = env is None
        check_options(kwargs, ARENA_OPTIONS | (RM_ARGUMENTS if served else set()), where,
                      _LENGTH_HINT if "max_cycles" in kwargs else "")  # fmt: skip
        seeded = {} if seed is None else {"seed": seed}
        if served:
            from neuronsmae.client.rm import RM

            return RM(**{"time_scale": 0.0, **kwargs, **seeded}), seed is not None
        arena = resolve(env)(**kwargs, **seeded)  # type: ignore[arg-type]
        return _checked(arena, ArenaAPI, env), seed is not None
    _refuse_beside(kwargs, seed)
    return _given(env, ArenaAPI), True


def open_vec_arena(
    env: Any,
    seed: int | None,
    num_envs: int,
    kwargs: Mapping[str, Any],
    where: str,
) -> tuple[VecArenaAPI, bool]:
    """:func:`open_arena` for ``num_envs`` arenas: a ``VecRM`` on one private vector server,
    a named ``VecArenaAPI`` class (``"neuronsmae.server:VecArena"``), or the caller's."""
    if env is None or isinstance(env, str):
        served = env is None
        check_options(kwargs, ARENA_OPTIONS | (VEC_RM_ARGUMENTS if served else set()), where)
        seeded = {} if seed is None else {"seed": seed}
        if served:
            from neuronsmae.client.vec_rm import VecRM

            check_fork_safe()  # before launching anything

            vec = VecRM(num_envs=num_envs, **{**kwargs, **seeded})
            return vec, seed is not None
        made = resolve(env, "vector")(num_envs=num_envs, **kwargs, **seeded)  # type: ignore[arg-type]
        return _checked(made, VecArenaAPI, env), seed is not None
    _refuse_beside(kwargs, seed)
    vec = _given(env, VecArenaAPI)
    if vec.num_envs != num_envs:
        vec.close()
        raise InvalidOptionError(f"num_envs={num_envs} but env holds {vec.num_envs} arenas")
    return vec, True


def make_arena(env: ArenaSource = None, seed: int | None = None, **options: Any) -> ArenaAPI:
    """One arena from ``env`` as the faces take it: None (a private unpaced server),
    ``"inprocess"`` (the server's ``Arena`` in this process, imported by name), a
    ``"module:attr"`` name, an arena or a factory; ``options`` are the arena options (and
    ``RM``'s, for a server). The caller closes it."""
    return open_arena(env, seed, options, "make_arena")[0]


def make_vec_arena(
    env: Any = None, seed: int | None = None, num_envs: int = 1, **options: Any
) -> VecArenaAPI:
    """``num_envs`` arenas behind the ``VecArenaAPI`` from ``env`` as :func:`make_arena`
    takes it (``"inprocess"``: the server's ``VecArena``; None: a ``VecRM`` on a private
    vector server). The caller closes it."""
    return open_vec_arena(env, seed, num_envs, options, "make_vec_arena")[0]


_LENGTH_HINT = (
    " (an episode's length is episode_steps, in physics steps of 0.02 s: 1000 = 20 s, the paper's)"
)


def _refuse_beside(kwargs: Mapping[str, Any], seed: int | None) -> None:
    """Options cannot apply to an arena that is already built: refuse them rather than
    silently ignore them."""
    given = sorted(kwargs) + ([] if seed is None else ["seed"])
    if given:
        raise InvalidOptionError(
            f"options {given} only configure an arena the face builds (env=None or a "
            "'module:attr' name); pass them to the arena (or factory) you give as env instead"
        )


def _given(env: Any, kind: type) -> Any:
    """The arena the caller gave as ``env``: the arena itself or what its factory builds."""
    if isinstance(env, kind):
        return env
    if not callable(env):
        raise InvalidOptionError(
            f"env must be an {kind.__name__}, a zero-argument factory of one, a 'module:attr' "
            f"name of an arena class, or None (a private served arena), got {env!r:.80}"
        )
    return _checked(env(), kind, env)


def _checked(arena: Any, kind: type, source: Any) -> Any:
    if not isinstance(arena, kind):
        raise InvalidOptionError(
            f"env={source!r} gave {type(arena).__name__}, not an {kind.__name__}"
        )
    return arena


def entropy_seed(span: int = 1) -> int:
    """A seed drawn from the operating system's entropy such that ``seed + span - 1`` is
    still a valid seed (vector arenas are seeded ``seed + i``)."""
    return int(np.random.SeedSequence().entropy) % (MAX_SEED - span + 2)


class FirstSeed:
    """Gymnasium's seeding for a face: the first reset without a seed gets one from entropy
    unless the constructor was given a seed; every other reset keeps the caller's seed
    (None continues the arena's own RNG, as ``ArenaAPI.reset`` says)."""

    def __init__(self, seeded: bool, span: int = 1) -> None:
        self.pending = not seeded
        """Whether the next reset without a seed still needs one from entropy."""
        self.span = span

    def __call__(self, seed: Any) -> Any:
        """The seed to pass to the arena's reset."""
        if self.pending and seed is None:
            seed = entropy_seed(self.span)
        self.pending = False
        return seed


def open_face(
    env: ArenaSource,
    seed: int | None,
    kwargs: Mapping[str, Any],
    render_mode: str | None,
    where: str,
    check: Callable[[Layout], None] | None = None,
) -> tuple[ArenaAPI, Layout, bool]:
    """What every one-arena face does first: check ``render_mode`` and the options, open the
    arena (:func:`open_arena`), read its layout and run ``check`` on it. Returns the arena,
    its layout and whether its first episode is seeded by construction. If anything fails,
    an arena built here is closed (nobody else could); one the caller passed in stays
    theirs."""
    check_render_mode(render_mode)
    key = repr((sorted(kwargs.items()), seed)) if env is None else ""
    if env is None:
        try:
            check_fork_safe()
        except ForkedZenohError as exc:
            if key not in _SERVED_INFO:
                raise
            arena: ArenaAPI = ForkedArena(exc, _SERVED_INFO[key])
            return arena, Layout.of(arena), True
    arena, seeded = open_arena(env, seed, kwargs, where)
    try:
        layout = Layout.of(arena)
        if check is not None:
            check(layout)
    except BaseException:
        if not isinstance(env, ArenaAPI):
            arena.close()
        raise
    if env is None:
        _SERVED_INFO[key] = layout.info.to_dict()
    return arena, layout, seeded


class Recipe(EzPickle):
    """Pickled as the arguments a face was built with (Gymnasium's ``EzPickle``): a face
    calls ``Recipe.__init__(self, env=env, seed=seed, ...)`` with every argument it was given,
    and unpickling builds a new face from them (``copy.deepcopy`` too)."""

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Build a face from the recipe and take over what it opened. The face built here
        is then emptied and marked closed: a Gymnasium ``VectorEnv`` closes itself when
        collected, which would close the arenas (and stop the servers) now this one's."""
        built = type(self)(*state["_ezpickle_args"], **state["_ezpickle_kwargs"])
        self.__dict__.update(built.__dict__)
        built.__dict__.clear()
        built.__dict__["closed"] = True

    def __getstate__(self) -> dict[str, Any]:
        env = self._ezpickle_kwargs.get("env")
        if isinstance(env, (ArenaAPI, VecArenaAPI)):
            name = "VecArena" if isinstance(env, VecArenaAPI) else "Arena"
            raise NotCopyableError(
                f"{type(self).__name__}(env=<{type(env).__name__} object>) cannot be copied: "
                "a copy is built anew from the constructor's arguments, and an arena object "
                "cannot be; give env as None (a private server), a 'module:attr' name such as "
                f"'neuronsmae.server:{name}', or a factory"
            )
        return super().__getstate__()  # type: ignore[no-any-return]


_SERVED_INFO: dict[str, dict[str, Any]] = {}
"""The env info of each served arena this process has built, by the face's arguments: what
a child forked from this process reads its spaces from (see :class:`ForkedArena`)."""


class ForkedArena(ArenaAPI):
    """Stands for a served arena in a child forked after its parent used Zenoh, where no
    arena can be reached: it knows the layout (from the parent's memory) and raises the
    :class:`ForkedZenohError` from everything else.

    Why not raise at once: Gymnasium's ``AsyncVectorEnv`` (whose default context on Linux is
    ``fork``) builds each environment in its worker outside its error handling, so an error
    there reaches the parent as a bare ``ConnectionResetError``; an error from ``reset`` is
    sent to the parent and raised there as itself, saying to use ``context="spawn"``.
    Nothing is launched in the child.
    """

    def __init__(self, error: ForkedZenohError, env_info: Mapping[str, Any]) -> None:
        self._error, self._info = error, dict(env_info)

    def reset(self, contexts: Any = None, seed: Any = None) -> Any:
        raise self._error

    def step(self, actions: Any) -> Any:
        raise self._error

    def get_obs(self) -> Any:
        raise self._error

    def get_state(self) -> Any:
        raise self._error

    def get_avail_actions(self) -> Any:
        raise self._error

    def get_env_info(self) -> dict[str, Any]:
        return dict(self._info)

    def render(self) -> Any:
        raise self._error

    def close(self) -> None:
        """Nothing to release."""
