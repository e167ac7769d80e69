"""The defaults every entry point shares, written once: port, seed and pace.

Both sides read them (the server's commands and classes, the client's ``RM`` and
``VecRM``, the launcher); a default is never spelled out anywhere else.

Pace: a server steps its arenas at most ``time_scale`` times real time (0: as fast as the
CPU allows). What stands in for the released build — ``RM``, and the server commands
``neuronsmae-server`` and ``neuronsmae-fleet`` — keeps the build's 100 (about 250
decisions/s), so the released scripts run as they did; everything opened to train or to
measure — ``VecRM``, the faces, a server launched by a library call, ``ArenaService`` — is
unpaced, since pacing only slows learning down.
"""

from __future__ import annotations

DEFAULT_PORT = 10000
"""The released wrapper's port (``RM(port=10000)``; its workers took 10000 + i): the
one-server command's port and a fleet's first."""
DEFAULT_SEED = 1234
"""The released wrapper's seed (``RM(seed=1234)``): an arena's seed when none is given, and
the servers' first arena's."""
RELEASED_TIME_SCALE = 100.0
"""The released build's pace (``time_scale=100``): ``RM``'s and the server commands'
default (see the module docstring)."""
UNPACED = 0.0
"""No pace: the default of everything opened to train or to measure."""
DEFAULT_HOST = "127.0.0.1"
"""Where a server listens and a client looks unless told otherwise: this machine only."""
