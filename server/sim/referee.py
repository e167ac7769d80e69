"""The referee: HP and bullet accounting, kills, the end of the episode and the rewards.

Rewards are the same for every robot of a team and zero-sum between the teams: each robot
gets 0.01 per HP of net team damage (dealt minus taken), 3 per kill and 20 for a win, minus
the same for losses (the paper's r_h, r_k, r_w). Sparse rewards keep only the win/loss term,
as ±1. All amounts are kept per team so a wrapper can build its own reward from ``info``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from neuronsmae.server.sim import field as F
from neuronsmae.server.sim.shots import (
    FL_BULLETS,
    FL_DEALT,
    FL_HP,
    FL_SCALE,
    FL_TAKEN,
    IT_KILLS,
    IT_PLATE,
    IT_TEAM,
    fire,
    with_trig,
)

R_DAMAGE = 0.01
R_KILL = 3.0
R_WIN = 20.0
R_SPARSE = 1.0
BLUE, RED = 0, 1
TEAM_NAMES = ("blue", "red")
_NO_DRAWS = np.zeros(0)


@dataclass
class StepTally:
    """What happened to each team during one decision, for rewards and info."""

    damage: np.ndarray
    """(2,) HP dealt by each team."""
    kills: np.ndarray
    """(2,) robots each team destroyed."""

    @classmethod
    def zero(cls) -> StepTally:
        return cls(np.zeros(2), np.zeros(2))


class Referee:
    """Keeps HP, bullets and the score for ``n_blue + n_red`` robots (blue first)."""

    def __init__(
        self,
        n_blue: int,
        n_red: int,
        rng: np.random.Generator,
        sampled: bool,
        by_damage: bool = False,
    ) -> None:
        self.by_damage = by_damage
        """At the time limit, compare the damage each team dealt instead of its HP left."""
        self.n = n_blue + n_red
        self.n_blue = n_blue
        self.team = np.array([BLUE] * n_blue + [RED] * n_red, dtype=np.int64)
        self.rng = rng
        self.sampled = sampled
        self.static_boxes = F.obstacle_array(tall_only=True)
        self.n_static = len(self.static_boxes)
        # Tall obstacles, then one scratch row per robot: the ray tests' blockers.
        self.boxes = with_trig(np.concatenate([self.static_boxes, np.zeros((self.n, 6))]))
        self.reset(np.full(self.n, float(F.START_HP)), coef=1.0)

    def reset(
        self, max_hp: np.ndarray, coef: float, max_bullets: float = float(F.START_BULLETS)
    ) -> None:
        """Full HP and bullets; ``coef`` scales the damage red deals; ``max_bullets`` is the
        most a robot can hold in the episode (the start's 370, more with the zones'
        ammunition bonuses), which observations divide by.

        The per-robot arrays are rows of two packed arrays, ``fl`` (float, ``FL_*`` rows) and
        ``it`` (int, ``IT_*`` rows), so the per-step kernel takes few arguments; ``hp``,
        ``bullets`` and the rest are views into them (edit them in place, do not rebind).
        """
        self.max_hp = max_hp.astype(np.float64)
        self.max_bullets = np.full(self.n, max_bullets)
        self.fl = np.zeros((6, self.n))
        self.it = np.zeros((3, self.n), dtype=np.int64)
        self.hp, self.bullets = self.fl[FL_HP], self.fl[FL_BULLETS]
        self.damage_dealt, self.damage_taken = self.fl[FL_DEALT], self.fl[FL_TAKEN]
        self.scale = self.fl[FL_SCALE]
        self.kills, self.last_plate = self.it[IT_KILLS], self.it[IT_PLATE]
        self.hp[:] = self.max_hp
        self.bullets[:] = float(F.START_BULLETS)
        self.scale[:] = np.where(self.team == RED, coef, 1.0)
        self.it[IT_TEAM] = self.team
        self.last_plate[:] = -1
        self.alive = np.ones(self.n, dtype=bool)
        self.coef = coef
        self.winner: str | None = None
        self._both_alive = True

    def draws(self) -> np.ndarray:
        """This step's uniform numbers for sampled hits (empty for expected damage)."""
        return self.rng.random(self.n) if self.sampled else _NO_DRAWS

    def physics_step(self, poses: np.ndarray, targets: np.ndarray, tally: StepTally) -> int:
        """Every live robot with bullets and a valid target fires once; apply the damage.

        Returns how many robots were destroyed in this step. (The arena's hot loop runs the
        same kernel fused with the pose readout, :mod:`~neuronsmae.server.sim.stepper`.)
        """
        destroyed = fire(
            poses, self.alive, self.fl, self.it, targets, self.boxes, self.n_static,
            self.draws(), tally.damage, tally.kills,
        )  # fmt: skip
        if destroyed:
            self.after_kills()
        return destroyed

    def after_kills(self) -> None:
        """Bookkeeping after a step that destroyed robots: is the episode decided?"""
        self._both_alive = bool(self.alive[: self.n_blue].any() and self.alive[self.n_blue :].any())

    def check_end(self, t: int, limit: int) -> bool:
        """Decide the winner on annihilation or at the time limit; return whether it ended."""
        if t < limit and self._both_alive:
            return False
        blue_alive = self.alive[: self.n_blue].any()
        red_alive = self.alive[self.n_blue :].any()
        if blue_alive and red_alive and t < limit:
            return False
        if blue_alive != red_alive:
            self.winner = "blue" if blue_alive else "red"
        else:  # time is up with both standing, or both fell in one step (then HP: a draw)
            score = self.damage_dealt if self.by_damage and blue_alive else self.hp
            blue, red = score[self.team == BLUE].sum(), score[self.team == RED].sum()
            self.winner = "draw" if np.isclose(blue, red) else ("blue" if blue > red else "red")
        return True

    def team_rewards(self, tally: StepTally, dense: bool) -> tuple[np.ndarray, dict[str, float]]:
        """(2,) reward per robot of each team for a decision, and blue's reward components."""
        win = 0.0
        if self.winner in TEAM_NAMES:
            win = 1.0 if self.winner == "blue" else -1.0
        if dense:
            damage, kills = tally.damage.tolist(), tally.kills.tolist()
            parts = {
                "damage": R_DAMAGE * (damage[BLUE] - damage[RED]),
                "kill": R_KILL * (kills[BLUE] - kills[RED]),
                "win": R_WIN * win,
            }
        else:
            parts = {"damage": 0.0, "kill": 0.0, "win": R_SPARSE * win}
        blue = sum(parts.values())
        return np.array([blue, -blue]), parts

    def info(self) -> dict[str, object]:
        """Per-robot tallies (blue first) and the winner, as plain Python values."""
        return {
            "hp": self.hp.tolist(),
            "bullets": self.bullets.astype(int).tolist(),
            "damage_dealt": self.damage_dealt.tolist(),
            "damage_taken": self.damage_taken.tolist(),
            "kills": self.kills.tolist(),
            "alive": self.alive.tolist(),
            "winner": self.winner,
        }
