"""Infos fit for tensors: what every face reports after ``reset`` and each ``step``.

The arena's own ``info`` mixes lists, a nested dict (``components``), a string or None
(``winner``) and, with zones, a log of events. Tensor-based libraries (TorchRL, RLlib) and
loggers that sum or average infos (EPyMARL, PyMARL) need numbers only, and need the same
keys after ``reset`` as after ``step`` to build their specs. So the faces report these
instead, from the point of view of one team (the agent's), the same keys after ``reset``
(the values an episode starts with) as after every step:

Scalars (:data:`SCALAR_KEYS`; SMAC's keys where SMAC has one):

* ``t`` (int): physics steps (0.02 s) elapsed in the episode; 0 after reset.
* ``battle_won`` (bool): the referee named this team the winner: the other team was wiped
  out, or it had more HP left at the time limit. False until the episode ends.
* ``episode_limit`` (bool): the episode ended at the time limit with both teams standing
  (the face's ``truncated``); SMAC's key, which EPyMARL and PyMARL read to bootstrap.
* ``dead_allies``, ``dead_enemies`` (int): robots of this team / the other team destroyed.
* ``reward_damage``, ``reward_kill``, ``reward_win`` (float): this decision's reward in
  parts, for this team (their sum is its reward); 0 after reset.

Per robot (:data:`ROBOT_KEYS`), arrays with one entry per robot, blue robots first:

* ``alive`` (bool), ``hp_fraction`` and ``bullets_fraction`` (float32, in [0, 1], read
  from the global state: HP over the robot's starting HP; bullets over the most it can
  hold in the episode, its starting 370, or with the ``zones`` option also the ammunition
  bonuses the episode can bring, so 370 / 470 at the start of a 20 s episode),
  ``damage_dealt`` and ``damage_taken`` (float64, HP so far this episode), ``kills``
  (int64).

What is left out is still there: the faces keep the arena's last ``info`` unchanged as
``arena_info`` (``winner`` as a string, ``components``, ``targets``, ``contacts``, and the
``zones`` and ``zone_log`` of ``zones=True``).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from neuronsmae.protocol.env_info import EnvInfo

SCALAR_KEYS = (
    "t", "battle_won", "episode_limit", "dead_allies", "dead_enemies",
    "reward_damage", "reward_kill", "reward_win",
)  # fmt: skip
"""The scalar keys, in order: what every face's info holds (EPyMARL's logger sums them)."""
ROBOT_KEYS = ("alive", "hp_fraction", "bullets_fraction", "damage_dealt", "damage_taken", "kills")
"""The per-robot array keys (blue robots first)."""
TEAMS = ("blue", "red")
"""Team names in the arena's order: team 0 is blue, team 1 red."""


def start_info(info: EnvInfo, state: np.ndarray, robots: bool = True) -> dict[str, Any]:
    """The info of an episode's start (after ``reset``; the same for both teams); without
    ``robots``, the scalars only."""
    n = info.state.n_robots
    out: dict[str, Any] = {
        "t": 0, "battle_won": False, "episode_limit": False, "dead_allies": 0,
        "dead_enemies": 0, "reward_damage": 0.0, "reward_kill": 0.0, "reward_win": 0.0,
    }  # fmt: skip
    if robots:
        out |= {
            "alive": np.ones(n, dtype=bool),
            **_fractions(info, state),
            "damage_dealt": np.zeros(n),
            "damage_taken": np.zeros(n),
            "kills": np.zeros(n, dtype=np.int64),
        }
    return out


def step_info(
    info: EnvInfo,
    raw: Mapping[str, Any],
    state: np.ndarray,
    team: int,
    truncated: bool,
    robots: bool = True,
) -> dict[str, Any]:
    """The numeric info of a step for ``team`` (0 blue, 1 red) from the arena's ``raw`` info
    and the global ``state`` after the step; ``truncated`` is whether the episode ended at
    the time limit with both teams standing. Without ``robots``, the scalars only."""
    alive = np.asarray(raw["alive"], dtype=bool)
    blue = info.state.n_blue
    own, other = (alive[:blue], alive[blue:]) if team == 0 else (alive[blue:], alive[:blue])
    sign = 1.0 if team == 0 else -1.0  # the components are blue's; red's reward is -blue's
    parts = raw.get("components") or {}
    out: dict[str, Any] = {
        "t": int(raw["t"]),
        "battle_won": raw.get("winner") == TEAMS[team],
        "episode_limit": bool(truncated),
        "dead_allies": int((~own).sum()),
        "dead_enemies": int((~other).sum()),
        "reward_damage": sign * float(parts.get("damage", 0.0)),
        "reward_kill": sign * float(parts.get("kill", 0.0)),
        "reward_win": sign * float(parts.get("win", 0.0)),
    }
    if robots:
        out |= {
            "alive": alive,
            **_fractions(info, state),
            "damage_dealt": np.asarray(raw["damage_dealt"], dtype=np.float64),
            "damage_taken": np.asarray(raw["damage_taken"], dtype=np.float64),
            "kills": np.asarray(raw["kills"], dtype=np.int64),
        }
    return out


def copy_info(info: Mapping[str, Any]) -> dict[str, Any]:
    """A copy whose arrays are fresh too (one per agent, so no agent's info aliases
    another's)."""
    return {k: v.copy() if isinstance(v, np.ndarray) else v for k, v in info.items()}


def _fractions(info: EnvInfo, state: np.ndarray) -> dict[str, np.ndarray]:
    """HP and bullets left, as fractions of the start, from the state's [-1, 1] columns."""
    layout = info.state
    robots = range(layout.n_robots)
    hp = np.asarray(state)[[layout.hp_of(r) for r in robots]]
    bullets = np.asarray(state)[[layout.bullets_of(r) for r in robots]]
    return {
        "hp_fraction": ((hp + 1.0) / 2.0).astype(np.float32),
        "bullets_fraction": ((bullets + 1.0) / 2.0).astype(np.float32),
    }
