"""Messages, codec, errors and the environment interface shared by server and client.

This package is the only code the server and the client have in common.
"""

from __future__ import annotations

from neuronsmae.protocol.errors import (
    BusyError,
    ForkedZenohError,
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    MalformedMessageError,
    MessageTooLargeError,
    NeuronsMAEError,
    ResetNeededError,
    ServerError,
    ServerUnavailableError,
    VersionMismatchError,
)
from neuronsmae.protocol.interface import ArenaAPI, VecArenaAPI

__all__ = [
    "ArenaAPI",
    "BusyError",
    "ForkedZenohError",
    "InvalidActionError",
    "InvalidContextError",
    "InvalidOptionError",
    "MalformedMessageError",
    "MessageTooLargeError",
    "NeuronsMAEError",
    "ResetNeededError",
    "ServerError",
    "ServerUnavailableError",
    "VecArenaAPI",
    "VersionMismatchError",
]
