"""Arena options: the constructor arguments of :class:`neuronsmae.server.Arena`.

Options fix the *shape* of the task for the lifetime of an arena (spaces, team sizes,
observability, rewards), while contexts (:mod:`neuronsmae.server.contexts`) vary per episode.
Validation happens here, once, so the simulation code can trust its inputs.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, listed
from neuronsmae.protocol.levels import level_error, level_value

ACTION_SPACES = ("abstract", "discrete", "continuous")
MODES = ("cooperative", "competitive", "bots")
OBSERVABILITY = ("full", "partial")
REWARDS = ("dense", "sparse")
SPAWNS = ("random", "corners")
HIT_MODES = ("expected", "sampled")
TIME_LIMIT_WINNERS = ("hp", "damage")


@dataclass(frozen=True)
class ArenaConfig:
    """Everything that fixes the task's shape; see docs/options.md for the table."""

    action_space: str = "abstract"
    """"abstract" (target × candidate point), "discrete" (target × stop/fwd/back/left/right)
    or "continuous" ((vx, vy, ω) plus target)."""
    n_blue: int = 2
    """Robots on the blue team (the learning team in cooperative mode), 1 to 3."""
    n_red: int = 2
    """Robots on the red team (the bot in cooperative mode), 1 to 3."""
    mode: str = "cooperative"
    """"cooperative": the caller drives blue, a bot drives red; "competitive": the caller
    drives both (blue agents first); "bots": bots drive both (for matches)."""
    blue_level: int | str = "easy"
    """The bot that drives blue in "bots" mode, and in "competitive" mode in the episodes reset
    with the context ``bot_team="blue"`` (red's bot is the ``level`` context); the same
    values as ``level``: the released build's 0 or 1, or a name (easy, middle, hard, random,
    middle_spread, hard_flank; docs/contexts.md, "Bots")."""
    decision_steps: int | None = None
    """Physics steps per decision, 1 to 1000; None → 20 (0.4 s), or 5 for discrete as released."""
    episode_steps: int = 1000
    """Physics steps per episode, 1 to 100,000 (1000 = 20 s)."""
    k: int = 4
    """Candidate points per enemy for the abstract action space and observation, 1 to 16."""
    candidate_obs: bool | None = None
    """Put candidate points in the vector observation; None → only for abstract actions."""
    observability: str = "full"
    """"full", or "partial": an enemy is seen only inside the camera's view and sight."""
    unseen_value: float = -1.0
    """The constant that pads an unseen enemy's pose and candidate points, in [-1, 1]."""
    camera_hfov_deg: float = 60.0
    """Horizontal field of view of the gimbal camera in degrees, 1 to 180 (the spec fixes
    only 27° vertical)."""
    vector_obs: bool = True
    """Include the referee vector (poses, candidates, time, HP, bullets) in observations."""
    lidar: bool = False
    """Append a 61-beam, 270° LiDAR scan, each range divided by ``lidar_range``, to [-1, 1]."""
    lidar_range: float = 8.0
    """LiDAR maximum range (m), 0.5 to 30."""
    reward: str = "dense"
    """"dense" (damage, kills, win) or "sparse" (win/loss only)."""
    spawn: str = "random"
    """"random" (the released build) or "corners" (the RMUA birth areas: each robot within
    0.15 m of its area's centre, facing the other side)."""
    zones: bool = False
    """Enable the RMUA bonus/penalty zones (the released build had them do nothing)."""
    gui: bool = False
    """Show PyBullet's own 3-D window of this arena (needs a display; one per process).
    The physics is identical to headless; ``render()`` stays the top-down image."""
    hit_mode: str = "expected"
    """"expected" damage per firing step, or "sampled" hits with that probability."""
    time_limit_winner: str = "hp"
    """Who wins when time is up with both teams standing: "hp", the team with more HP left
    (the released build), or "damage", the team that dealt more damage (the paper's text);
    equal is a draw. The two agree unless the teams start with unequal HP (the
    ``opponent_hp`` context) or the zones heal."""
    clip_actions: bool = False
    """Clip out-of-range continuous motion commands (vx, vy, omega) to their bounds instead
    of raising InvalidActionError. The target is a choice, not a command: one that is not an
    integer naming an enemy is refused either way."""
    planner_resolution: float = 0.04
    """Grid cell size of the abstract action planner (m), 0.02 to 0.2."""

    def __post_init__(self) -> None:
        for name, choices in (
            ("action_space", ACTION_SPACES),
            ("mode", MODES),
            ("observability", OBSERVABILITY),
            ("reward", REWARDS),
            ("spawn", SPAWNS),
            ("hit_mode", HIT_MODES),
            ("time_limit_winner", TIME_LIMIT_WINNERS),
        ):
            if getattr(self, name) not in choices:
                raise InvalidOptionError(
                    f"option {name}={getattr(self, name)!r:.80} is not valid; "
                    f"choose one of {choices}"
                )
        level = level_value(self.blue_level)
        if level is None:
            raise InvalidOptionError(level_error("option blue_level", self.blue_level))
        object.__setattr__(self, "blue_level", level)  # 1.0 → 1, as for the level context
        for name in ("vector_obs", "lidar", "zones", "gui", "clip_actions"):
            _check_bool(self, name)
        _check_bool(self, "candidate_obs", optional=True)
        _check_int(self, "n_blue", 1, 3)
        _check_int(self, "n_red", 1, 3)
        _check_int(self, "episode_steps", 1, 100_000)
        _check_int(self, "k", 1, 16)
        if self.decision_steps is not None:
            _check_int(self, "decision_steps", 1, 1000)
        _check_float(self, "lidar_range", 0.5, 30.0)
        _check_float(self, "camera_hfov_deg", 1.0, 180.0)
        _check_float(self, "unseen_value", -1.0, 1.0)
        _check_float(self, "planner_resolution", 0.02, 0.2)
        if self.mode == "competitive" and self.n_blue != self.n_red:
            raise InvalidOptionError(
                f"mode='competitive' needs equal teams (one observation and action layout for "
                f"every agent); got n_blue={self.n_blue}, n_red={self.n_red}"
            )
        if self.gui and sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
            raise InvalidOptionError(
                "option gui=True needs a display, and DISPLAY is not set (use render() instead)"
            )
        if not (self.vector_obs or self.lidar):
            raise InvalidOptionError("options vector_obs and lidar are both off: enable one")

    @property
    def period(self) -> int:
        """Physics steps per decision after applying the action-space default."""
        if self.decision_steps is not None:
            return self.decision_steps
        return 5 if self.action_space == "discrete" else 20

    @property
    def with_candidates(self) -> bool:
        """Whether candidate points appear in the vector observation."""
        if self.candidate_obs is None:
            return self.action_space == "abstract"
        return self.candidate_obs

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> ArenaConfig:
        """Build from keyword options; an unknown name is an error listing the valid ones."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(options) - names)
        if unknown:
            raise InvalidOptionError(
                f"unknown option(s) {listed(unknown)}; valid options: {sorted(names)}"
            )
        return cls(**dict(options))

    def to_dict(self) -> dict[str, Any]:
        """Plain dict of every option (for the wire, recordings and logs)."""
        return dataclasses.asdict(self)


def _is_bool(value: Any) -> bool:
    return isinstance(value, (bool, np.bool_))


def _check_int(cfg: ArenaConfig, name: str, lo: int, hi: int) -> None:
    """An integer option (NumPy's too, stored as a Python int) in [lo, hi]."""
    value = getattr(cfg, name)
    if _is_bool(value) or not isinstance(value, numbers.Integral) or not lo <= value <= hi:
        raise InvalidOptionError(f"option {name}={value!r:.80} must be an integer in [{lo}, {hi}]")
    object.__setattr__(cfg, name, int(value))


def _check_float(cfg: ArenaConfig, name: str, lo: float, hi: float) -> None:
    """A number option (NumPy's too, stored as a Python float) in [lo, hi]."""
    value = getattr(cfg, name)
    ok = isinstance(value, numbers.Real) and not _is_bool(value)
    if not ok or not math.isfinite(value) or not lo <= value <= hi:
        raise InvalidOptionError(f"option {name}={value!r:.80} must be a number in [{lo}, {hi}]")
    object.__setattr__(cfg, name, float(value))


def _check_bool(cfg: ArenaConfig, name: str, optional: bool = False) -> None:
    """A switch: True or False (NumPy's too; None too when ``optional``). A string such as
    "false" would otherwise count as on."""
    value = getattr(cfg, name)
    if optional and value is None:
        return
    if not _is_bool(value):
        valid = "True, False or None" if optional else "True or False"
        raise InvalidOptionError(f"option {name}={value!r:.80} must be {valid}")
    object.__setattr__(cfg, name, bool(value))
