"""The values of the ``level`` context (red's bot), shared by the server and its clients.

The server's context table advertises them, ``reset`` accepts them, and the command-line
tools and the trainers parse them, all from this one list (docs/contexts.md, "Bots").
"""

from __future__ import annotations

import numbers
from typing import Any

RELEASED_LEVELS: tuple[int, ...] = (0, 1)
"""The released build's ``level`` numbers: 0 = a random live target and random candidate
point per robot, redrawn each decision; 1 = the least-HP target, each robot from its own
nearest candidate point. Given as numbers (ints, or floats with an integer value such as
``1.0``, as the released scripts pass them)."""
LEVEL_NAMES: tuple[str, ...] = ("easy", "middle", "hard", "random", "middle_spread", "hard_flank")
"""Named ``level`` values: the paper's easy, middle and hard bots taken literally; random
(the released level 0's rule); this project's variants middle_spread and hard_flank
(docs/contexts.md, "Bots")."""
LEVEL_CHOICES: tuple[int | str, ...] = (*RELEASED_LEVELS, *LEVEL_NAMES)
"""Every value ``level`` accepts, with its type (as the context table advertises them)."""
DEFAULT_LEVEL = "easy"
"""The bot a reset without a ``level`` context gets."""


def level_value(value: Any) -> int | str | None:
    """``value`` as a level (:data:`LEVEL_CHOICES`), or None when it is not one.

    Numbers mean the released build's levels: an int, or a float with an integer value
    (``1.0`` → 1); booleans are not numbers here. Strings must be names: the strings "0" and
    "1" are refused (the released scripts pass numbers; the context table advertises ints).
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral):
        if not float(value).is_integer():
            return None
        value = int(value)
    if isinstance(value, numbers.Integral):
        return int(value) if int(value) in RELEASED_LEVELS else None
    if isinstance(value, str) and value in LEVEL_NAMES:
        return value
    return None


def level_error(field: str, value: Any) -> str:
    """The message for a bad level: names ``field`` and lists every valid value."""
    hint = ""
    if isinstance(value, str) and value.strip() in ("0", "1"):
        hint = f" (give the released level as the number {value.strip()}, not a string)"
    elif isinstance(value, (int, float)) and not isinstance(value, bool) and value == 2:
        hint = " (the released build had no level 2; the paper's hard bot is 'hard')"
    return (
        f"{field}={value!r:.80} is not valid{hint}; valid: the released build's levels "
        f"{list(RELEASED_LEVELS)} as numbers, or a name: {list(LEVEL_NAMES)} "
        "(the paper's bots are 'easy', 'middle' and 'hard')"
    )


LEVEL_ARGS: tuple[str, ...] = tuple(str(v) for v in LEVEL_CHOICES)
"""The levels as typed on a command line (``neuronsmae-match --red 1``): "0" and "1" are the
released numbers there, since a command line has only strings."""


def level_from_arg(text: str) -> int | str:
    """A command-line level (one of :data:`LEVEL_ARGS`) as the value ``reset`` takes."""
    return int(text) if text in ("0", "1") else text
