"""Rule-based opponents as small finite-state machines over the abstract action.

A bot sees the true scene (the referee's view) and, like an abstract-action agent, picks for
each of its robots a target enemy and one of the candidate points around that enemy; the
planner and chassis then drive it exactly as they drive a learning agent. Levels:

* random — a random live target and point, re-drawn each decision (the released level 0);
* easy   — attack the nearest enemy from the candidate point nearest to itself;
* middle — the team attacks the enemy with the least HP, each robot from a candidate point
  near itself: the nearest one, or, as both robots share the target, the pair of points with
  the least total travel that does not crowd them onto one spot;
* hard   — both robots besiege the least-HP enemy (the same target and tie-break as middle):
  the robot the target is facing holds its front from the nearest candidate point, and the
  other takes the candidate point most behind the target, where the side and rear plates
  take 2× and 3× damage.

Nearly every shot lands within 3 m and bullets run out before the time limit, so what a
bullet is worth depends on the plate it hits; the hard bot's edge is its flanker's plates.
Middle keeps the paper's rule: the team focuses the least-HP enemy, ties (equal HP, as at
the start) going to the enemy nearest the whole team, so both robots pick the same one; why
its two robots do not share one point is told in :class:`MiddleBot`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neuronsmae.server.task.candidates import ROBOT_CLEARANCE


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

CROWDING = 2 * ROBOT_CLEARANCE
"""Two points closer than this in both x and y (m) crowd each other: the ±0.6 m squares the
candidate filter keeps clear around a robot would overlap."""


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


def _uncrowded_pair(view: BotView, a: int, b: int, e: int) -> tuple[int, int] | None:
    """Candidate points for bot robots ``a`` and ``b`` around enemy ``e``: the pair with the
    least total travel that is not closer than :data:`CROWDING` in both x and y (None if
    every pair is)."""
    pa, pb = view.cands[a, e], view.cands[b, e]
    da = np.hypot(*(pa - view.poses[view.robots[a], :2]).T)
    db = np.hypot(*(pb - view.poses[view.robots[b], :2]).T)
    apart = (np.abs(pa[:, None] - pb[None]) >= CROWDING).any(axis=2)
    if not apart.any():
        return None
    cost = np.where(apart, da[:, None] + db[None], np.inf)
    x, y = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(x), int(y)


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
    """Least-HP enemy (nearest the team on ties), nearest candidate points that do not crowd.

    The paper's middle level: the team focuses the enemy with the least HP, ties (equal HP, as
    at the start) going to the enemy nearest the whole team so both robots pick the same one,
    and each robot drives to a candidate point near itself. Taken literally, "each its own
    nearest point" sends both robots to the same point or to neighbouring ones, so they meet
    the target from one side: the target faces one of them and both hit its front plate (×1),
    while the enemy left alone shoots at them. That literal bot won only about half its games
    against the easy bot (0.495 and 0.515 over 200 episodes at seeds 0 and 1000).

    So two robots on one target share out the candidate points: they take the pair with the
    least total travel whose ±0.6 m clearance squares (the candidate filter's) do not overlap,
    that is points at least :data:`CROWDING` apart in x or y; if no pair qualifies, each takes
    its nearest. They then stand apart around the target, so whichever robot it does not face
    often sees a side plate (×2). Against easy, that robot's side-plate hits went from about
    94 to 125 per episode, and the win rate over 1600 episodes (seeds 0-199, 1000-1199, ...,
    7000-7199) from 0.55 to 0.63. The choice looks only at travel, never at the target's
    heading: this is not the hard bot's flanking, which sends one robot round to the rear.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp(view, _live(view))
        out = [(e, _nearest_point(view, i, e)) for i in range(len(view.robots))]
        alive = [i for i, r in enumerate(view.robots) if view.alive[r]]
        if len(alive) == 2:
            pair = _uncrowded_pair(view, alive[0], alive[1], e)
            if pair is not None:
                out[alive[0]], out[alive[1]] = (e, pair[0]), (e, pair[1])
        return out


class HardBot:
    """Both robots besiege the least-HP enemy: one holds its front, the other takes its rear.

    A robot's chassis turns toward its own target, so the besieged enemy shows its front plate
    (×1) to the robot it is facing and its side (×2) or rear (×3) plates to anyone behind it;
    the shooter hits the nearest plate it can see. Most shots land within 3 m, so the plate,
    not the range, decides how much each bullet is worth, and bullets run out before the time
    limit. Roles per decision: the *holder* is the robot the target faces (the smaller angle
    off its heading) and keeps it facing that way from the nearest candidate point; the
    *flanker* takes the point most behind the target, a little discounted by travel, and
    never the holder's point.
    """

    TRAVEL = 0.1
    """Score lost per metre to a point; small, so the flanker will walk round the target."""
    CLAIMED = 0.8
    """Points closer than this (m) to the holder's point are left to the holder."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp(view, _live(view))
        target = view.poses[view.enemies[e]]
        out = [(e, _nearest_point(view, i, e)) for i in range(len(view.robots))]
        alive = [i for i, r in enumerate(view.robots) if view.alive[r]]
        if len(alive) == 1:
            out[alive[0]] = (e, self._flank_point(view, alive[0], e, target, None))
        elif len(alive) == 2:
            holder, flanker = sorted(alive, key=lambda i: _off_heading(view, i, target))
            held = view.cands[holder, e, out[holder][1]]
            out[flanker] = (e, self._flank_point(view, flanker, e, target, held))
        return out

    def _flank_point(
        self, view: BotView, i: int, e: int, target: np.ndarray, held: np.ndarray | None
    ) -> int:
        """The candidate point most behind the target's heading, less travel; not ``held``."""
        pts = view.cands[i, e]
        rel = np.arctan2(pts[:, 1] - target[1], pts[:, 0] - target[0]) - target[2]
        travel = np.hypot(*(pts - view.poses[view.robots[i], :2]).T)
        score = -np.cos(rel) - self.TRAVEL * travel
        if held is not None:
            score = score - 10.0 * (np.hypot(*(pts - held).T) < self.CLAIMED)
        return int(np.argmax(score))


def _off_heading(view: BotView, i: int, target: np.ndarray) -> float:
    """How far (rad) bot robot ``i`` is off the target's heading, as seen from the target."""
    d = view.poses[view.robots[i], :2] - target[:2]
    return abs(float(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - target[2])))))


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
