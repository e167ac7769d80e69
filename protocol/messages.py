"""Typed request and reply messages, and their msgpack wire form.

A request is one msgpack map: the envelope fields ``v`` (protocol version), ``type`` and
``session`` plus the fields of the message named by ``type``. A reply is
``{"ok": true, "value": ...}`` or ``{"ok": false, "code": ..., "message": ...}``, where
``code`` is a wire code of :mod:`neuronsmae.protocol.errors`. See ``protocol/README.md`` for
the field-by-field description a client in another language can be written from.

Decoding is strict (no missing, extra or mistyped fields) because a server must turn every
malformed request into a typed error reply instead of guessing, and because strictness
within one protocol version is what makes a version bump meaningful.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from neuronsmae.protocol.codec import decode, encode
from neuronsmae.protocol.errors import (
    MalformedMessageError,
    NeuronsMAEError,
    VersionMismatchError,
)

PROTOCOL_VERSION = 2
"""The version this code speaks: 2 added the vector messages (``vreset``, ``vstep``,
``vget``) and the ``arenas`` fields. Bumped on any incompatible change."""
SUPPORTED_VERSIONS = (1, 2)
"""Versions a server answers. Version 1 is version 2 without the vector messages, the
``arenas`` fields and ``ping``'s ``pid``, so a version-1 client keeps working against a
one-arena server: its replies speak version 1 (:func:`reply_in_version`)."""
MAX_REQUEST_BYTES = 1 << 20
"""Largest request a server decodes (1 MiB); requests carry actions and options, never
images, so anything bigger is a mistake or an attack."""
MAX_REPLY_BYTES = 256 << 20
"""Largest reply a client decodes (256 MiB; renders and LiDAR observations are big)."""
NOT_CONFIGURED = "not_configured"
"""Error code the server sends to a session it has no configuration for (e.g. after a
restart). Clients answer it by sending ``configure`` again; it never reaches user code."""


class NotConfiguredError(NeuronsMAEError):
    """The session sent a request before ``configure`` (or the server restarted since).

    Not in ``errors.ERRORS`` on purpose: the client handles it by configuring again."""

    code = NOT_CONFIGURED


GET_TARGETS = ("obs", "state", "avail_actions", "env_info")
"""What a ``get`` request may ask for; each maps to the ``ArenaAPI`` method ``get_<what>``."""
MAX_SEED = 2**63 - 1
MAX_ARENAS = 64
"""Most arenas one server may hold (``neuronsmae-server --arenas``)."""


def max_first_seed(arenas: int) -> int:
    """Largest seed of arena 0 when ``arenas`` arenas take ``seed, seed + 1, ...``: the last
    one must stay within :data:`MAX_SEED`."""
    return MAX_SEED - (arenas - 1)


def rpc_key(port: int) -> str:
    """The key expression a server on ``port`` serves; the port in it keeps servers apart."""
    return f"neuronsmae/{port}/rpc"


# ---- field checkers: each returns the (possibly normalised) value or raises ----------------


def _bad(name: str, expected: str, value: Any) -> MalformedMessageError:
    return MalformedMessageError(
        f"field {name!r} must be {expected}, got {type(value).__name__} {value!r:.80}"
    )


def _seed(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise _bad(name, "an integer", value)
    if not 0 <= int(value) <= MAX_SEED:
        raise _bad(name, f"in [0, {MAX_SEED}]", value)
    return int(value)


def _optional(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    return lambda name, value: None if value is None else check(name, value)


def _str_map(name: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict) or not all(isinstance(key, str) for key in value):
        raise _bad(name, "a map with string keys", value)
    return value


def _actions(name: str, value: Any) -> list[Any] | np.ndarray:
    if isinstance(value, np.ndarray) and value.ndim >= 1:
        return value
    if not isinstance(value, list):
        raise _bad(name, "a list or an array with one entry per agent", value)
    return value


def _arenas(name: str, value: Any) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise _bad(name, "an integer", value)
    if not 1 <= int(value) <= MAX_ARENAS:
        raise _bad(name, f"in [1, {MAX_ARENAS}]", value)
    return int(value)


def _per_arena(check: Callable[[str, Any], Any]) -> Callable[[str, Any], Any]:
    """A list with one entry per arena, each nil or passing ``check`` (the service checks
    the length, which only it knows)."""

    def checked(name: str, value: Any) -> list[Any]:
        if not isinstance(value, list):
            raise _bad(name, "an array with one entry (or nil) per arena", value)
        return [None if v is None else check(f"{name}[{i}]", v) for i, v in enumerate(value)]

    return checked


def _contexts_for_all(name: str, value: Any) -> dict[str, Any] | list[Any]:
    """One contexts map for every arena, or an array of one map (or nil) per arena."""
    if isinstance(value, dict):
        return _str_map(name, value)
    return _per_arena(_str_map)(name, value)


def _flags(name: str, value: Any) -> list[bool]:
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype == np.bool_:
        return value.tolist()
    if not isinstance(value, list) or not all(isinstance(v, bool) for v in value):
        raise _bad(name, "an array of booleans, one per arena", value)
    return value


def _target(name: str, value: Any) -> str:
    if value not in GET_TARGETS:
        raise _bad(name, f"one of {list(GET_TARGETS)}", value)
    return value


def _check(fn: Callable[[str, Any], Any]) -> dict[str, Any]:
    """Dataclass field metadata naming the wire checker of the field."""
    return {"check": fn}


# ---- requests ------------------------------------------------------------------------------


class Message:
    """Base of every request body; ``TYPE`` is its wire ``type`` string."""

    TYPE: ClassVar[str] = ""


@dataclass(frozen=True)
class Configure(Message):
    """Claim the server for this session and build its arenas from ``seed`` and ``options``.

    ``seed`` None keeps the server's default (its ``--seed``); arena i gets ``seed + i``.
    ``arenas`` is how many arenas the client expects the server to hold (None: 1); another
    count than the server's ``--arenas`` is refused with ``invalid_option``."""

    TYPE: ClassVar[str] = "configure"
    seed: int | None = field(default=None, metadata=_check(_optional(_seed)))
    options: dict[str, Any] = field(default_factory=dict, metadata=_check(_str_map))
    arenas: int | None = field(default=None, metadata=_check(_optional(_arenas)))


@dataclass(frozen=True)
class Reset(Message):
    """``ArenaAPI.reset(contexts, seed)``."""

    TYPE: ClassVar[str] = "reset"
    contexts: dict[str, Any] | None = field(default=None, metadata=_check(_optional(_str_map)))
    seed: int | None = field(default=None, metadata=_check(_optional(_seed)))


@dataclass(frozen=True)
class Step(Message):
    """``ArenaAPI.step(actions)``."""

    TYPE: ClassVar[str] = "step"
    actions: Any = field(metadata=_check(_actions))


@dataclass(frozen=True)
class Get(Message):
    """``ArenaAPI.get_<what>()`` for ``what`` in :data:`GET_TARGETS`."""

    TYPE: ClassVar[str] = "get"
    what: str = field(metadata=_check(_target))


@dataclass(frozen=True)
class VReset(Message):
    """Reset every arena of the server: ``VecArenaAPI.reset``.

    ``contexts``: one map for all arenas, or one map (or nil) per arena; ``seeds``: one
    seed (or nil) per arena."""

    TYPE: ClassVar[str] = "vreset"
    contexts: dict[str, Any] | list[Any] | None = field(
        default=None, metadata=_check(_optional(_contexts_for_all))
    )
    seeds: list[int | None] | None = field(
        default=None, metadata=_check(_optional(_per_arena(_seed)))
    )


@dataclass(frozen=True)
class VStep(Message):
    """One decision in every active arena: ``VecArenaAPI.step``.

    ``actions`` has one row per arena. An arena whose episode ended at the previous step is
    reset instead (its row is ignored), with its entry of ``seeds`` and ``contexts`` when
    given. ``active`` (one bool per arena; nil: all) leaves the arenas marked false
    untouched."""

    TYPE: ClassVar[str] = "vstep"
    actions: Any = field(metadata=_check(_actions))
    seeds: list[int | None] | None = field(
        default=None, metadata=_check(_optional(_per_arena(_seed)))
    )
    contexts: list[Any] | None = field(
        default=None, metadata=_check(_optional(_per_arena(_str_map)))
    )
    active: list[bool] | None = field(default=None, metadata=_check(_optional(_flags)))


@dataclass(frozen=True)
class VGet(Message):
    """``VecArenaAPI.get_<what>()``: every arena's value, stacked."""

    TYPE: ClassVar[str] = "vget"
    what: str = field(metadata=_check(_target))


@dataclass(frozen=True)
class Contexts(Message):
    """The server's context table: every reset key with its default and range."""

    TYPE: ClassVar[str] = "contexts"


@dataclass(frozen=True)
class Render(Message):
    """``ArenaAPI.render()``."""

    TYPE: ClassVar[str] = "render"


@dataclass(frozen=True)
class Ping(Message):
    """Liveness and identity; answered to any session, owner or not."""

    TYPE: ClassVar[str] = "ping"


@dataclass(frozen=True)
class Close(Message):
    """Give up ownership of the server (the server and its arena keep running)."""

    TYPE: ClassVar[str] = "close"


MESSAGES: dict[str, type[Message]] = {
    cls.TYPE: cls
    for cls in (Configure, Reset, Step, Get, Contexts, Render, Ping, Close, VReset, VStep, VGet)
}
VECTOR_MESSAGES: frozenset[type[Message]] = frozenset({VReset, VStep, VGet})
"""Messages that address every arena of a server at once (protocol version 2)."""
ENVELOPE = ("v", "type", "session")


@dataclass(frozen=True)
class Request:
    """A decoded request: which session sent which message, in which protocol version."""

    body: Message
    session: str = ""
    version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class _Field:
    """One wire field of a message class: its name, checker and whether it may be left out."""

    name: str
    check: Callable[[str, Any], Any]
    required: bool


@functools.cache
def _fields_of(cls: type[Message]) -> tuple[tuple[_Field, ...], frozenset[str]]:
    """The wire fields of ``cls`` and every key a request of it may hold (read once per
    class: a request's hot path then touches no dataclass machinery)."""
    fields = tuple(
        _Field(
            f.name,
            f.metadata["check"],
            f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING,
        )
        for f in dataclasses.fields(cls)  # type: ignore[arg-type]
    )
    return fields, frozenset(f.name for f in fields) | frozenset(ENVELOPE)


def encode_request(body: Message, session: str = "") -> bytes:
    """The wire bytes of ``body`` sent by ``session``."""
    wire = {"v": PROTOCOL_VERSION, "type": body.TYPE, "session": session}
    for f in _fields_of(type(body))[0]:
        wire[f.name] = getattr(body, f.name)
    return encode(wire)


def decode_request(data: bytes | bytearray | memoryview) -> Request:
    """Decode and validate a request; raise the typed error the server should reply with.

    The version is checked before anything else, so a client of another version gets
    ``VersionMismatchError`` rather than a complaint about fields it did not know about.
    """
    wire = decode(data, max_bytes=MAX_REQUEST_BYTES)
    if not isinstance(wire, dict):
        raise MalformedMessageError(f"a request must be a map, got {type(wire).__name__}")
    if "v" not in wire:
        raise MalformedMessageError("request lacks the protocol version field 'v'")
    version = wire["v"]
    if type(version) is not int or version not in SUPPORTED_VERSIONS:
        raise VersionMismatchError(
            f"client speaks protocol version {version!r}, server speaks "
            f"{' and '.join(map(str, SUPPORTED_VERSIONS))}"
        )
    kind = wire.get("type")
    cls = MESSAGES.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise MalformedMessageError(
            f"unknown request type {wire.get('type')!r:.40}; known: {sorted(MESSAGES)}"
        )
    if "session" not in wire:
        raise MalformedMessageError("request lacks the envelope field 'session'")
    session = wire["session"]
    if not isinstance(session, str) or len(session) > 128:
        raise _bad("session", "a string of at most 128 characters", session)
    if cls is Configure and not session:
        raise MalformedMessageError(
            "'configure' needs a non-empty 'session': ownership is by session id"
        )
    body = _body(cls, wire)
    if version < 2 and (cls in VECTOR_MESSAGES or getattr(body, "arenas", None) is not None):
        raise VersionMismatchError(
            f"{cls.TYPE!r} with these fields is protocol version 2; the request says v=1"
        )
    return Request(body=body, session=session, version=version)


def _body(cls: type[Message], wire: dict[Any, Any]) -> Message:
    fields, allowed = _fields_of(cls)
    if not allowed.issuperset(wire):
        names = sorted(map(repr, set(wire) - allowed))[:5]
        raise MalformedMessageError(f"{cls.TYPE!r} request has unknown fields {names}")
    values: dict[str, Any] = {}
    for f in fields:
        if f.name in wire:
            values[f.name] = f.check(f.name, wire[f.name])
        elif f.required:
            raise MalformedMessageError(f"{cls.TYPE!r} request lacks field {f.name!r}")
    return cls(**values)


# ---- replies -------------------------------------------------------------------------------

ADDED_IN_2: dict[type[Message], tuple[str, ...]] = {Configure: ("arenas",), Ping: ("arenas", "pid")}
"""Reply fields that version 2 added, per request type: a version-1 reply goes without them."""


def reply_in_version(kind: type[Message], value: Any, version: int) -> Any:
    """``value``, a reply to a ``kind`` request, as protocol ``version`` has it: the replies
    that carry a ``version`` field (``configure``, ``ping``) carry the request's, and a
    version-1 reply leaves out the fields of :data:`ADDED_IN_2`, so a version-1 client gets
    exactly what a version-1 server sent."""
    if version >= PROTOCOL_VERSION or kind not in ADDED_IN_2 or not isinstance(value, dict):
        return value
    added = ADDED_IN_2[kind]
    return {**{k: v for k, v in value.items() if k not in added}, "version": version}


@dataclass(frozen=True)
class OkReply:
    """A request succeeded; ``value`` is what the ``ArenaAPI`` method returns.

    ``snapshot`` (``reset`` and ``step`` replies only) holds what ``get_state`` and
    ``get_avail_actions`` return right after the request. A trainer reads both after every
    decision, so carrying them here saves two round trips per decision.
    """

    value: Any = None
    snapshot: dict[str, Any] | None = None


@dataclass(frozen=True)
class ErrorReply:
    """A request failed; ``code`` names the error class (see ``errors.ERRORS``)."""

    code: str
    message: str

    @classmethod
    def from_exception(cls, exc: NeuronsMAEError) -> ErrorReply:
        return cls(code=exc.code, message=str(exc))


Reply = OkReply | ErrorReply


def encode_reply(reply: Reply) -> bytes:
    """The wire bytes of a reply; an unencodable value raises ``MalformedMessageError``."""
    if isinstance(reply, OkReply):
        wire = {"ok": True, "value": reply.value}
        if reply.snapshot is not None:
            wire["snapshot"] = reply.snapshot
        return encode(wire)
    return encode({"ok": False, "code": reply.code, "message": reply.message})


def decode_reply(data: bytes | bytearray | memoryview) -> Reply:
    """Decode a reply; a reply that is not one raises ``MalformedMessageError``."""
    wire = decode(data, max_bytes=MAX_REPLY_BYTES)
    if (
        isinstance(wire, dict)
        and wire.get("ok") is True
        and set(wire) in ({"ok", "value"}, {"ok", "value", "snapshot"})
        and isinstance(wire.get("snapshot", {}), dict)
    ):
        return OkReply(wire["value"], wire.get("snapshot"))
    if (
        isinstance(wire, dict)
        and wire.get("ok") is False
        and isinstance(wire.get("code"), str)
        and isinstance(wire.get("message"), str)
    ):
        return ErrorReply(wire["code"], wire["message"])
    raise MalformedMessageError("the server's reply is not a valid reply map")
