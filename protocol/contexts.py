"""The context table: the per-episode keys a ``reset`` takes, their defaults and ranges.

Described once here, for both sides of the wire: the arena builds an episode from them
(``server/contexts.py``), a server advertises them in its ``contexts`` reply, and a trainer
checks its contexts against them before it starts any worker. The keys keep the released
build's names so the original scripts' dictionaries (``{"coef": 0.5, "level": 1.0}``,
``{"VK1": 0.0375, "level": 0}``) work unchanged. Dynamics keys apply to the learning team
(blue); the same key behind ``opponent.`` (for example ``"opponent.VK1"``) applies to the
red team. Keys left out take their defaults (docs/contexts.md).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from neuronsmae.protocol.errors import InvalidContextError, listed
from neuronsmae.protocol.interface import plain_contexts
from neuronsmae.protocol.levels import (
    DEFAULT_LEVEL,
    LEVEL_CHOICES,
    level_error,
    level_value,
)


@dataclass(frozen=True)
class ContextKey:
    """One row of the context table."""

    name: str
    default: float
    lo: float
    hi: float
    doc: str
    chassis_field: str | None = None
    """The ``ChassisParams`` field this key sets, for dynamics keys."""


DYNAMICS_KEYS: tuple[ContextKey, ...] = (
    ContextKey(
        "Friction_coeff", 0.1, 0.0, 2.0, "sliding friction μ (rolling is 0.8μ)", "friction_coeff"
    ),
    ContextKey("KP", 8.0, 0.0, 200.0, "wheel PID proportional gain", "kp"),
    ContextKey("KI", 0.0, 0.0, 200.0, "wheel PID integral gain", "ki"),
    ContextKey("KD", 2.0, 0.0, 200.0, "wheel PID derivative gain", "kd"),
    ContextKey("VK1", 0.375, 1e-4, 10.0, "motor torque constant (motor character)", "vk1"),
    ContextKey("M", 3.4, 0.1, 100.0, "mass in the wheel model (kg)", "m"),
    ContextKey("Wheel_I", 0.0125, 1e-4, 1.0, "wheel rotational inertia (kg m²)", "wheel_i"),
    ContextKey("vx_dt", 0.0, 0.0, 2.0, "lateral command delay (s)", "vx_dt"),
    ContextKey("vy_dt", 0.0, 0.0, 2.0, "forward command delay (s)", "vy_dt"),
    ContextKey("vw_dt", 0.0, 0.0, 2.0, "yaw-rate command delay (s)", "vw_dt"),
)
OTHER_KEYS: tuple[ContextKey, ...] = (
    ContextKey("coef", 1.0, 0.0, 10.0, "multiplies the damage the red team deals"),
    ContextKey("opponent_hp", 600.0, 1.0, 10000.0, "starting HP of each red robot"),
    ContextKey("opponent_speed", 1.0, 0.1, 3.0, "multiplies the red robots' velocity commands"),
)
OPPONENT_PREFIX = "opponent."

CONTEXT_TABLE: dict[str, ContextKey] = {k.name: k for k in DYNAMICS_KEYS + OTHER_KEYS}
CONTEXT_TABLE.update({OPPONENT_PREFIX + k.name: k for k in DYNAMICS_KEYS})

BOT_TEAMS: tuple[str, ...] = ("none", "red", "blue")
"""Values of the ``bot_team`` context: which team a bot drives in ``mode="competitive"``
("none": the caller drives both; "red": the ``level`` bot drives red; "blue": the
``blue_level`` option's bot drives blue). The team a bot drives ignores its action rows."""
BOT_TEAM_DOC = (
    "competitive mode: the team a bot drives this episode (none: the caller drives both; "
    "red: the level bot; blue: the blue_level bot); that team's actions are ignored"
)


LEVEL_DOC = (
    "opponent bot: the released build's levels 0 (random target and point) and 1 (least-HP "
    "target, each robot's nearest point; the same rule as middle), the paper's easy, middle, "
    "hard, random (= 0), or this project's variants middle_spread, hard_flank"
)


def context_table() -> list[dict[str, Any]]:
    """The table of keys, defaults, ranges and meanings (served to remote clients).

    The ``level`` row's ``choices`` are exactly the values ``reset`` accepts, with their
    types: the ints 0 and 1 and the names (a float such as ``1.0`` is accepted as 1 too).
    """
    rows = [
        {"key": name, "default": k.default, "min": k.lo, "max": k.hi, "doc": k.doc}
        for name, k in CONTEXT_TABLE.items()
    ]
    rows.append(
        {
            "key": "level",
            "default": DEFAULT_LEVEL,
            "choices": list(LEVEL_CHOICES),
            "doc": LEVEL_DOC,
        }
    )
    rows.append(
        {"key": "bot_team", "default": "none", "choices": list(BOT_TEAMS), "doc": BOT_TEAM_DOC}
    )
    return rows


def _valid_keys() -> list[str]:
    """Every key a reset's contexts may hold, for error messages."""
    return sorted([*CONTEXT_TABLE, "level", "bot_team"])


@dataclass(frozen=True)
class CheckedContexts:
    """A reset's contexts, checked: what :func:`check_contexts` returns."""

    values: dict[str, float]
    """The numeric keys given (table names), as floats within their ranges."""
    level: int | str = DEFAULT_LEVEL
    """Red's bot level (``protocol.levels``)."""
    bot_team: str = "none"
    """The team a bot drives in competitive mode (:data:`BOT_TEAMS`)."""


def check_contexts(contexts: Mapping[str, Any] | None) -> CheckedContexts:
    """Validate a reset's contexts; raise InvalidContextError naming the key and what is valid.
    NumPy scalar values count as the Python numbers they hold (bools stay refused)."""
    contexts = plain_contexts(contexts) or {}
    bad = [key for key in contexts if not isinstance(key, str)]
    if bad:
        raise InvalidContextError(
            f"context keys must be strings, got {listed(bad)}; valid keys: {_valid_keys()}"
        )
    values: dict[str, float] = {}
    level, bot_team = DEFAULT_LEVEL, "none"
    for key, value in contexts.items():
        if key == "level":
            level = _parse_level(value)
            continue
        if key == "bot_team":
            if not isinstance(value, str) or value not in BOT_TEAMS:
                raise InvalidContextError(
                    f"context 'bot_team'={value!r:.80} is not valid; "
                    f"choose one of {list(BOT_TEAMS)}"
                )
            bot_team = value
            continue
        spec = CONTEXT_TABLE.get(key)
        if spec is None:
            raise InvalidContextError(
                f"unknown context key {key!r:.80}; valid keys: {_valid_keys()}"
            )
        values[key] = _check_value(key, value, spec)
    return CheckedContexts(values, level, bot_team)


def _check_value(key: str, value: Any, spec: ContextKey) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):  # NumPy: plain_contexts
        raise InvalidContextError(
            f"context {key!r} must be a number in [{spec.lo}, {spec.hi}], got {value!r:.80}"
        )
    value = float(value)
    if not math.isfinite(value) or not spec.lo <= value <= spec.hi:
        raise InvalidContextError(
            f"context {key!r}={value!r:.80} is out of range; valid: [{spec.lo}, {spec.hi}]"
        )
    return value


def _parse_level(value: Any) -> int | str:
    level = level_value(value)
    if level is None:
        raise InvalidContextError(level_error("context 'level'", value))
    return level
