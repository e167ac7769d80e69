"""The typed error hierarchy shared by the in-process arena, the server and the client.

Every error the environment can raise on purpose is a :class:`NeuronsMAEError`. Each has a
stable wire ``code`` so that a server can send it as an error reply and the client can raise
the *same* exception type again (see :func:`error_from_code`). Errors caused by bad input
also subclass :class:`ValueError`, so ``except ValueError`` keeps working for callers that
only care that the input was wrong.
"""

from __future__ import annotations

from collections.abc import Iterable


class NeuronsMAEError(Exception):
    """Base class of every error NeuronsMAE raises on purpose."""

    code: str = "error"


class InvalidActionError(NeuronsMAEError, ValueError):
    """An action has the wrong count, type, index, or a value outside its space."""

    code = "invalid_action"


class InvalidContextError(NeuronsMAEError, ValueError):
    """A reset context names an unknown key or a value out of its range, or the reset seed
    is not an integer in [0, 2⁶³ − 1]."""

    code = "invalid_context"


class InvalidOptionError(NeuronsMAEError, ValueError):
    """An arena option (constructor argument) is unknown or out of range."""

    code = "invalid_option"


class ResetNeededError(NeuronsMAEError, RuntimeError):
    """``step`` was called before ``reset`` or after the episode ended."""

    code = "reset_needed"


class VersionMismatchError(NeuronsMAEError):
    """Client and server speak different protocol versions."""

    code = "version_mismatch"


class MessageTooLargeError(NeuronsMAEError, ValueError):
    """A request exceeds the protocol's size limit."""

    code = "message_too_large"


class MalformedMessageError(NeuronsMAEError, ValueError):
    """A request could not be decoded or lacks a required field."""

    code = "malformed_message"


class BusyError(NeuronsMAEError):
    """The server's episode is owned by another client."""

    code = "busy"


class ServerUnavailableError(NeuronsMAEError, ConnectionError):
    """Nothing answered within the timeout (server dead, unreachable or not started)."""

    code = "unavailable"


class ServerError(NeuronsMAEError):
    """The server failed on a request for a reason that is not the caller's input."""

    code = "server_error"


ERRORS: dict[str, type[NeuronsMAEError]] = {
    cls.code: cls
    for cls in (
        NeuronsMAEError,
        InvalidActionError,
        InvalidContextError,
        InvalidOptionError,
        ResetNeededError,
        VersionMismatchError,
        MessageTooLargeError,
        MalformedMessageError,
        BusyError,
        ServerUnavailableError,
        ServerError,
    )
}


def listed(items: Iterable[object], limit: int = 8, width: int = 40) -> str:
    """``items`` for an error message, bounded however many (or long) they are: the first
    ``limit`` reprs, each cut to ``width`` characters, and how many more there are; so an
    error reply never echoes a whole oversized request."""
    items = list(items)
    shown = ", ".join(f"{item!r:.{width}}" for item in items[:limit])
    more = f", ... ({len(items) - limit} more, {len(items)} in all)" if len(items) > limit else ""
    return f"[{shown}{more}]"


def error_from_code(code: str, message: str) -> NeuronsMAEError:
    """Rebuild an exception from its wire code; an unknown code becomes :class:`ServerError`."""
    return ERRORS.get(code, ServerError)(message)


# --- local errors (never sent over the wire, so not in ERRORS) ----------------------------


class RecordingFormatError(NeuronsMAEError, ValueError):
    """An episode recording cannot be read: not gzip/JSON, wrong format name or version,
    or a line lacks a required field."""

    code = "bad_recording"


class ReplayMismatchError(NeuronsMAEError):
    """Re-simulating a recording diverged from it; ``decision`` is the first that differs
    (0 = the state right after ``reset``)."""

    code = "replay_mismatch"

    def __init__(self, message: str, decision: int = -1) -> None:
        super().__init__(message)
        self.decision = decision


class ClosedError(NeuronsMAEError, RuntimeError):
    """An in-process arena (or a trainer) was used after ``close()``, which released its
    simulation (or workers): build a new one."""

    code = "closed"


class ForkedZenohError(NeuronsMAEError, RuntimeError):
    """A Zenoh session was asked for in a child forked from a process that had already
    opened one; Zenoh's runtime does not survive ``fork``. The message says how to start
    the child instead (the ``spawn`` context)."""

    code = "forked_zenoh"


class EnvInfoError(NeuronsMAEError, ValueError):
    """An env info dict (``get_env_info()``) lacks a key, has a value of the wrong type, or
    gives sizes that do not fit its own layout."""

    code = "bad_env_info"


class NotCopyableError(NeuronsMAEError, TypeError):
    """An environment was asked to be pickled (or copied) that cannot be rebuilt from its
    arguments, such as a face wrapping an arena object; a ``TypeError``, as ``pickle``
    raises for objects it cannot pickle. The message says what to give instead."""

    code = "not_copyable"


class MissingDependencyError(NeuronsMAEError, ImportError):
    """An optional feature needs a package that is not installed; the message names the
    ``pip install 'neuronsmae[extra]'`` that adds it."""

    code = "missing_dependency"
