"""Messages, codec, errors and the environment interface shared by server and client.

This package is the only code the server and the client have in common.
"""

from __future__ import annotations

from neuronsmae.protocol.env_info import V_MAX, W_MAX, EnvInfo, ObsLayout, StateLayout
from neuronsmae.protocol.errors import (
    BusyError,
    EnvInfoError,
    ForkedZenohError,
    InvalidActionError,
    InvalidContextError,
    InvalidOptionError,
    MalformedMessageError,
    MessageTooLargeError,
    NeuronsMAEError,
    NotCopyableError,
    ResetNeededError,
    ServerError,
    ServerUnavailableError,
    VersionMismatchError,
)
from neuronsmae.protocol.interface import ArenaAPI, VecArenaAPI

__all__ = [
    "V_MAX",
    "W_MAX",
    "ArenaAPI",
    "BusyError",
    "EnvInfo",
    "EnvInfoError",
    "ForkedZenohError",
    "InvalidActionError",
    "InvalidContextError",
    "InvalidOptionError",
    "MalformedMessageError",
    "MessageTooLargeError",
    "NeuronsMAEError",
    "NotCopyableError",
    "ObsLayout",
    "ResetNeededError",
    "ServerError",
    "ServerUnavailableError",
    "StateLayout",
    "VecArenaAPI",
    "VersionMismatchError",
]
