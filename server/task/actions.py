"""Action spaces: validation, decoding into robot intents, and availability masks.

An *intent* is what one robot does for a decision: the enemy it aims at and how it moves —
toward a goal point through the planner (abstract), at a fixed body velocity with the
chassis turning toward the target (discrete), or at a commanded (vx, vy, ω) (continuous).
Bots produce intents of the abstract kind, so every robot is driven by the same code.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from neuronsmae.protocol.actions import check_joint

DISCRETE_SPEED = 1.0
DISCRETE_MOVES = ("stop", "forward", "back", "left", "right")
DISCRETE_VEL = np.array(
    [
        (0.0, 0.0),
        (DISCRETE_SPEED, 0.0),
        (-DISCRETE_SPEED, 0.0),
        (0.0, DISCRETE_SPEED),
        (0.0, -DISCRETE_SPEED),
    ]
)
"""Body-frame (forward, left) velocity of each discrete move."""

KIND_GOAL, KIND_BODY, KIND_CMD = 0, 1, 2


@dataclass
class Intent:
    """One robot's decision: target enemy (robot index) and motion."""

    target: int
    kind: int
    goal: np.ndarray | None = None
    """World (x, y) goal for KIND_GOAL."""
    vel: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Body (forward, left, ω) for KIND_CMD; (forward, left, -) for KIND_BODY."""


def n_actions(space: str, n_enemy: int, k: int) -> int:
    """Size of the flat discrete action set (the target choices for continuous)."""
    return {
        "abstract": n_enemy * k,
        "discrete": n_enemy * len(DISCRETE_MOVES),
        "continuous": n_enemy,
    }[space]


class ActionDecoder:
    """Checks a joint action and turns it into intents for the controlled robots."""

    def __init__(self, space: str, n_enemy: int, k: int, clip: bool) -> None:
        self.space = space
        self.n_enemy = n_enemy
        self.k = k
        self.clip = clip
        self.size = n_actions(space, n_enemy, k)
        self._first = _first_only(k)

    def validate(
        self, actions: Sequence[Any], n_agents: int, used: Sequence[bool] | None = None
    ) -> list[Any]:
        """Raise InvalidActionError for a wrong container, count, type, index, NaN or bound
        (:func:`~neuronsmae.protocol.actions.check_joint`; ``used`` as there)."""
        return check_joint(actions, n_agents, self.space, self.size, self.n_enemy, self.clip, used)

    def decode(self, action: Any, enemies: np.ndarray, cands: np.ndarray) -> Intent:
        """One validated action → intent. ``enemies`` are the robot indices of the enemies in
        observation order; ``cands`` (n_enemy, k, 2) the candidate points in the observation."""
        if self.space == "continuous":
            vx, vy, w, t = action
            return Intent(int(enemies[t]), KIND_CMD, vel=(vx, vy, w))
        if self.space == "abstract":
            e, c = divmod(action, self.k)
            return Intent(int(enemies[e]), KIND_GOAL, goal=cands[e, c])
        e, m = divmod(action, len(DISCRETE_MOVES))
        vf, vl = DISCRETE_VEL[m]
        return Intent(int(enemies[e]), KIND_BODY, vel=(vf, vl, 0.0))

    def mask(self, alive_self: bool, enemy_alive: np.ndarray, cand_valid: np.ndarray) -> np.ndarray:
        """int8 mask over the flat actions: dead robots only no-op; dead enemies are not
        targets; an enemy without candidate points offers only its first ("stay") point.

        ``enemy_alive`` is (n_enemy,) bool, ``cand_valid`` (n_enemy, k) bool."""
        m = np.zeros(self.size, dtype=np.int8)
        if not alive_self or not enemy_alive.any():
            m[0] = 1
            return m
        if self.space == "continuous":
            m[:] = enemy_alive
        elif self.space == "discrete":
            m[:] = np.repeat(enemy_alive, len(DISCRETE_MOVES))
        else:
            # Candidate rows are all real or, for the "stay" sentinel, all not: then only the
            # first (stay) point of that enemy is offered.
            block = cand_valid.any(axis=1)[:, None] | self._first
            m[:] = (block & enemy_alive[:, None]).reshape(-1)
        return m


def _first_only(k: int) -> np.ndarray:
    out = np.zeros(k, dtype=bool)
    out[0] = True
    return out
