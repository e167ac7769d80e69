"""Per-episode contexts: the episode an arena plays from a reset's checked contexts.

The table of keys, defaults and ranges is the protocol's (``protocol/contexts.py``,
docs/contexts.md); this module turns a reset's contexts into the chassis parameters of each
team and the referee's settings. Keys left out take their defaults, so an episode is
described completely by its seed and contexts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from neuronsmae.protocol.contexts import (
    CONTEXT_TABLE,
    DYNAMICS_KEYS,
    OPPONENT_PREFIX,
    check_contexts,
    context_table,
)
from neuronsmae.protocol.errors import InvalidContextError, NeuronsMAEError
from neuronsmae.protocol.interface import seed_value
from neuronsmae.protocol.levels import DEFAULT_LEVEL

__all__ = [
    "CONTEXT_TABLE",
    "DYNAMICS_KEYS",
    "MAX_SEED",
    "EpisodeContext",
    "check_seed",
    "context_table",
    "parse_contexts",
]


@dataclass(frozen=True)
class EpisodeContext:
    """Validated contexts of one episode."""

    blue_dynamics: dict[str, float] = field(default_factory=dict)
    """ChassisParams keyword values for blue robots."""
    red_dynamics: dict[str, float] = field(default_factory=dict)
    """ChassisParams keyword values for red robots (speed scaling included)."""
    coef: float = 1.0
    """Multiplies the damage the red team deals, [0, 10]; the paper's authors trained with 0.5."""
    opponent_hp: float = 600.0
    """Starting HP of each red robot, [1, 10000]."""
    level: int | str = DEFAULT_LEVEL
    """Red's bot: a released level number (0, 1; a float such as ``1.0`` becomes the int) or a
    name from :data:`LEVEL_NAMES`."""
    bot_team: str = "none"
    """Competitive mode: the team a bot drives this episode (:data:`BOT_TEAMS`); the other
    modes ignore it (red's bot drives red in cooperative mode, bots drive both in "bots")."""

    def to_dict(self) -> dict[str, Any]:
        """The contexts as given to reset (released names), for records and replays."""
        out: dict[str, Any] = {
            "coef": self.coef,
            "opponent_hp": self.opponent_hp,
            "level": self.level,
            "bot_team": self.bot_team,
        }
        for key in DYNAMICS_KEYS:
            assert key.chassis_field is not None
            out[key.name] = self.blue_dynamics[key.chassis_field]
            out[OPPONENT_PREFIX + key.name] = self.red_dynamics[key.chassis_field]
        out["opponent_speed"] = self.red_dynamics["speed_scale"]
        return out


def parse_contexts(contexts: Mapping[str, Any] | None) -> EpisodeContext:
    """The episode a reset's contexts describe (checked by
    :func:`~neuronsmae.protocol.contexts.check_contexts`: InvalidContextError naming the key
    and what is valid)."""
    checked = check_contexts(contexts)
    values = checked.values
    blue = {k.chassis_field: values.get(k.name, k.default) for k in DYNAMICS_KEYS}
    red = {k.chassis_field: values.get(OPPONENT_PREFIX + k.name, k.default) for k in DYNAMICS_KEYS}
    red["speed_scale"] = values.get("opponent_speed", 1.0)
    return EpisodeContext(
        blue_dynamics=blue,  # type: ignore[arg-type]
        red_dynamics=red,  # type: ignore[arg-type]
        coef=values.get("coef", 1.0),
        opponent_hp=values.get("opponent_hp", 600.0),
        level=checked.level,
        bot_team=checked.bot_team,
    )


MAX_SEED = 2**63 - 1
"""Largest reset seed (the wire's limit: a signed 64-bit integer)."""


def check_seed(seed: Any, error: type[NeuronsMAEError] = InvalidContextError) -> int:
    """A seed as an int, or ``error`` (a reset's ``InvalidContextError`` by default; an
    arena's constructor passes ``InvalidOptionError``) saying what is valid."""
    return seed_value(seed, error=error)
