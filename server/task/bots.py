"""Rule-based opponents as small finite-state machines over the abstract action.

A bot sees the true scene (the referee's view) and, like an abstract-action agent, picks for
each of its robots a target enemy and one of the candidate points around that enemy; the
planner and chassis then drive it exactly as they drive a learning agent. Levels:

* random — a random live target and point, re-drawn each decision (the released level 0);
* easy   — attack the nearest enemy from the candidate point nearest to itself;
* middle — attack the enemy with the least HP from the candidate point nearest to itself;
* hard   — both robots besiege the least-HP enemy from distinct points chosen for the
  damage they allow (behind and beside the target, where plates take 2–3×), and a robot
  low on HP falls back to the safest point while its team-mate keeps the siege.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neuronsmae.server.sim.field import obstacle_array
from neuronsmae.server.task.geometry import SIGHT_MIN_HEIGHT, segment_blocked

TALL = obstacle_array(tall_only=True)
LOW_HP_FRACTION = 0.25
"""The hard bot's retreat threshold, as a fraction of starting HP."""


@dataclass
class BotView:
    """What a team's bot sees at a decision."""

    robots: np.ndarray
    """Robot indices of the bot's team."""
    enemies: np.ndarray
    """Robot indices of the enemies, in the order candidate points are given."""
    poses: np.ndarray
    """(N, 3) every robot's pose."""
    hp: np.ndarray
    max_hp: np.ndarray
    alive: np.ndarray
    cands: np.ndarray
    """(n_team, n_enemy, k, 2) each bot robot's candidate points around each enemy."""
    valid: np.ndarray
    """(n_team, n_enemy, k) whether each candidate is real."""


Choice = tuple[int, int]
"""(enemy position in ``view.enemies``, candidate index)."""


def _live(view: BotView) -> np.ndarray:
    return np.flatnonzero(view.alive[view.enemies])


def _nearest_point(view: BotView, i: int, e: int) -> int:
    pts = view.cands[i, e]
    d = np.hypot(*(pts - view.poses[view.robots[i], :2]).T)
    return int(np.argmin(d))


def _least_hp(view: BotView, live: np.ndarray) -> int:
    """The live enemy with the least HP; ties go to the one nearest the whole team, so that
    every robot of the team picks the same enemy and their fire is focused."""
    mine = view.poses[view.robots[view.alive[view.robots]], :2]
    enemies = view.poses[view.enemies[live], :2]
    dist = np.hypot(*(enemies[:, None] - mine[None]).transpose(2, 0, 1)).sum(axis=1)
    keys = np.lexsort((dist, np.round(view.hp[view.enemies[live]], 6)))
    return int(live[keys[0]])


class RandomBot:
    """Released level 0: random live target and random point."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        live = _live(view)
        k = view.cands.shape[2]
        return [(int(self.rng.choice(live)), int(self.rng.integers(k))) for _ in view.robots]


class EasyBot:
    """Nearest enemy, nearest candidate point."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        live = _live(view)
        out = []
        for i, r in enumerate(view.robots):
            d = np.hypot(*(view.poses[view.enemies[live], :2] - view.poses[r, :2]).T)
            e = int(live[np.argmin(d)])
            out.append((e, _nearest_point(view, i, e)))
        return out


class MiddleBot:
    """Least-HP enemy (nearest on ties), nearest candidate point."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        live = _live(view)
        out = []
        e = _least_hp(view, live)
        for i in range(len(view.robots)):
            out.append((e, _nearest_point(view, i, e)))
        return out


class HardBot:
    """Besiege the weakest enemy from distinct, high-damage points; retreat when weak.

    The target is the enemy the team can destroy soonest: its HP over the damage rate the
    bot's robots would deal it from where they stand (distance band, line of sight, and the
    plate each one faces), with hysteresis so the siege does not flip between enemies.
    States per robot: ``siege`` (default) and ``retreat`` (HP below 25 %: go to the
    candidate point farthest from every other enemy, still shooting at the target).
    """

    SWITCH = 0.7
    """A new target must be this much quicker to destroy than the current one."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.target: int | None = None

    def _time_to_kill(self, view: BotView, j: int) -> float:
        enemy = view.poses[view.enemies[j]]
        rate = 0.0
        for r in view.robots[view.alive[view.robots]]:
            me = view.poses[r, :2]
            d = float(np.hypot(*(me - enemy[:2])))
            if d >= 9.0 or segment_blocked(me, enemy[:2], TALL, SIGHT_MIN_HEIGHT):
                continue
            rel = abs(np.angle(np.exp(1j * (np.arctan2(*(me - enemy[:2])[::-1]) - enemy[2]))))
            plate = 1.0 if rel < np.pi / 4 else (3.0 if rel > 3 * np.pi / 4 else 2.0)
            rate += (1.0 if d < 3.0 else 0.5 if d < 6.0 else 0.2) * plate
        return float(view.hp[view.enemies[j]]) / max(rate, 0.1)

    def _pick(self, view: BotView, live: np.ndarray) -> int:
        ttk = {int(j): self._time_to_kill(view, int(j)) for j in live}
        best = min(ttk, key=ttk.__getitem__)
        if self.target in ttk and ttk[best] > self.SWITCH * ttk[self.target]:
            best = self.target
        self.target = best
        return best

    def act(self, view: BotView) -> list[Choice]:
        live = _live(view)
        e = self._pick(view, live)
        target = view.poses[view.enemies[e]]
        taken: list[np.ndarray] = []
        out: list[Choice] = []
        for i, r in enumerate(view.robots):
            pts = view.cands[i, e]
            me = view.poses[r, :2]
            exposure = self._exposure(view, pts, live, e)
            if view.hp[r] < LOW_HP_FRACTION * view.max_hp[r]:
                score = self._safety(view, pts, live, e) - 2.0 * exposure
            else:
                score = self._siege_score(pts, target, me) - 1.5 * exposure
            for p in taken:  # distinct points: spread the siege around the target
                score = score - 5.0 * (np.hypot(*(pts - p).T) < 0.8)
            c = int(np.argmax(score))
            taken.append(pts[c])
            out.append((e, c))
        return out

    @staticmethod
    def _siege_score(pts: np.ndarray, target: np.ndarray, me: np.ndarray) -> np.ndarray:
        # Points behind the target's heading see its rear (×3) or side (×2) plates.
        rel = np.arctan2(pts[:, 1] - target[1], pts[:, 0] - target[0]) - target[2]
        behind = -np.cos(rel)
        travel = np.hypot(*(pts - me).T)
        return 1.0 * behind - 0.6 * travel

    @staticmethod
    def _exposure(view: BotView, pts: np.ndarray, live: np.ndarray, e: int) -> np.ndarray:
        """Expected hit factor the *other* live enemies would have on each point."""
        out = np.zeros(len(pts))
        for j in live:
            if j == e:
                continue
            other = view.poses[view.enemies[j], :2]
            for c, p in enumerate(pts):
                d = float(np.hypot(*(p - other)))
                if d < 9.0 and not segment_blocked(p, other, TALL, SIGHT_MIN_HEIGHT):
                    out[c] += 1.0 if d < 3.0 else (0.5 if d < 6.0 else 0.2)
        return out

    @staticmethod
    def _safety(view: BotView, pts: np.ndarray, live: np.ndarray, e: int) -> np.ndarray:
        others = [view.poses[view.enemies[j], :2] for j in live if j != e]
        if not others:
            return -np.hypot(*(pts - view.poses[view.enemies[e], :2]).T)
        return np.min([np.hypot(*(pts - o).T) for o in others], axis=0)


BOTS: dict[str, Callable[[np.random.Generator], RandomBot | EasyBot | MiddleBot | HardBot]] = {
    "random": RandomBot,
    "easy": EasyBot,
    "middle": MiddleBot,
    "hard": HardBot,
}
"""Bot classes by level name; the ``level`` context picks one."""


def make_bot(level: str, rng: np.random.Generator) -> RandomBot | EasyBot | MiddleBot | HardBot:
    """A bot for ``level`` (one of ``BOTS``)."""
    return BOTS[level](rng)
