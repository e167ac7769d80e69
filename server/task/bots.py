"""Rule-based opponents as small finite-state machines over the abstract action.

A bot sees the true scene (the referee's view) and, like an abstract-action agent, picks for
each of its robots a target enemy and one of the candidate points around that enemy; the
planner and chassis then drive it exactly as they drive a learning agent. Every bot decides
afresh at every decision. Where each rule comes from (docs/contexts.md, "Bots"):

* released build, level ``0`` (also the name ``random``) — :class:`RandomBot`: a random
  live target and a random candidate point per robot, drawn from the arena's RNG;
* the paper's ``middle`` — :class:`MiddleBot`: attack the live enemy with the least HP (a
  plain argmin over the enemies in order: ties go to the first), each robot from its own
  nearest candidate point of that enemy, the paper's sentence read literally;
* released build, level ``1`` — :class:`ReleasedLevel1Bot`: middle's target, and R1's
  nearest point as middle's, but R2 takes its nearest point *other than R1's* (the
  build's managed code, docs/reference.md);
* the paper's ``easy`` — :class:`EasyBot`: each robot attacks its nearest live enemy from
  its own nearest candidate point of that enemy;
* the paper's ``hard`` — :class:`HardBot`: "two robots siege the robot with the least HP at
  the best candidate points"; the least-HP rule is middle's, and "best" is defined there;
* this project's variants, never the default for a paper name — :class:`MiddleSpreadBot`
  (``middle_spread``: middle whose two robots do not share one point) and
  :class:`HardFlankBot` (``hard_flank``: a holder in front, a flanker behind).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from neuronsmae.server.sim import field as F
from neuronsmae.server.sim.shots import hit_factor, select_shots, with_trig
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


class Bot(Protocol):
    """What the arena asks of a bot: one choice per robot of its team at each decision."""

    def act(self, view: BotView) -> list[Choice]: ...


CROWDING = 2 * ROBOT_CLEARANCE
"""Two points closer than this in both x and y (m) crowd each other: the ±0.6 m squares the
candidate filter keeps clear around a robot would overlap (``middle_spread``'s spacing)."""


def _live(view: BotView) -> np.ndarray:
    return np.flatnonzero(view.alive[view.enemies])


def _travel(view: BotView, i: int, e: int) -> np.ndarray:
    """Straight-line distance (m) from bot robot ``i`` to each of its points around ``e``."""
    return np.hypot(*(view.cands[i, e] - view.poses[view.robots[i], :2]).T)


def _nearest_point(view: BotView, i: int, e: int) -> int:
    return int(np.argmin(_travel(view, i, e)))


def _least_hp(view: BotView, live: np.ndarray) -> int:
    """The live enemy with the least HP: a plain argmin over the live enemies in order, so
    ties (equal HP, as at the start) go to the first of them and every robot of the team
    picks the same enemy."""
    return int(live[np.argmin(view.hp[view.enemies[live]])])


def _least_hp_nearest_team(view: BotView, live: np.ndarray) -> int:
    """The live enemy with the least HP; ties go to the one nearest the whole team (the
    tie-break of this project's variants ``middle_spread`` and ``hard_flank``)."""
    mine = view.poses[view.robots[view.alive[view.robots]], :2]
    enemies = view.poses[view.enemies[live], :2]
    dist = np.hypot(*(enemies[:, None] - mine[None]).transpose(2, 0, 1)).sum(axis=1)
    keys = np.lexsort((dist, np.round(view.hp[view.enemies[live]], 6)))
    return int(live[keys[0]])


class RandomBot:
    """Released level 0 (and ``random``): a random live target and a random candidate point
    for each robot, redrawn at every decision from the arena's RNG (so reproducible per
    seed)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        live = _live(view)
        k = view.cands.shape[2]
        return [(int(self.rng.choice(live)), int(self.rng.integers(k))) for _ in view.robots]


class EasyBot:
    """The paper's easy bot: "goes to the nearest candidate point to attack the nearest robot".

    Each robot on its own: the live enemy nearest to it (ties: the first in order), and its
    own nearest candidate point around that enemy.
    """

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
    """The paper's middle bot, its sentence read literally.

    Paper: "The middle bot goes to the nearest candidate point to attack the robot with the
    least HP." The team attacks the live enemy with the least HP, a plain argmin over the
    enemies in order, so ties (equal HP, as at the start) go to the first enemy and both
    robots share the target; each robot drives to its own nearest candidate point around it
    (two robots may pick the same point; the planner keeps them from overlapping). The
    released build's level 1 differs in one point: :class:`ReleasedLevel1Bot`.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp(view, _live(view))
        return [(e, _nearest_point(view, i, e)) for i in range(len(view.robots))]


class ReleasedLevel1Bot:
    """The released build's level 1, as its managed code has it: the live enemy with the
    lower HP (ties: the first), R1 at that enemy's candidate point nearest itself, and R2 at
    the point nearest itself *excluding R1's* (docs/reference.md, "The released Unity
    build"). More robots follow R2's rule: each skips the points the live robots before it
    took. Points are excluded by their slot in the enemy's list of ``k`` (what the build
    indexes; a robot's list differs from its mate's only where its own clearance square
    dropped a sample), and only a live robot takes one. With every slot taken the robot
    takes its nearest anyway.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp(view, _live(view))
        taken: list[int] = []
        out = []
        for i, r in enumerate(view.robots):
            travel = _travel(view, i, e)
            free = np.ones(travel.size, dtype=bool)
            free[taken] = False
            if not free.any():
                free[:] = True
            c = int(np.argmin(np.where(free, travel, np.inf)))
            if view.alive[r]:
                taken.append(c)
            out.append((e, c))
        return out


_STATIC_BOXES = F.obstacle_array(tall_only=True)
"""The tall obstacles, the only static things that block a shot (the referee's blockers)."""


def point_damage(points: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Expected damage per firing step (hit factor × plate multiplier) of a shooter standing
    at each of ``points`` (n, 2) and facing ``target`` (x, y, yaw) as it stands now.

    The referee's own shot rule (:func:`~neuronsmae.server.sim.shots.select_shots`) decides:
    the nearest plate whose bearing is within ±0.52 rad of the shooter's heading, met at more
    than 35° and not hidden by a tall obstacle; 0 when there is none. Only static obstacles
    block here: robots move, the field does not.
    """
    n = len(points)
    poses = np.empty((n + 1, 3))
    poses[:n, :2] = points
    poses[:n, 2] = np.arctan2(target[1] - points[:, 1], target[0] - points[:, 0])
    poses[n] = target
    targets = np.full(n + 1, n, dtype=np.int64)
    targets[n] = -1
    robots = np.zeros((n + 1, 6))  # robots do not block: zero-size, zero-height boxes
    boxes = with_trig(np.concatenate([_STATIC_BOXES, robots]))
    plate = np.empty(n + 1, dtype=np.int64)
    dist = np.empty(n + 1)
    select_shots(
        poses, np.ones(n + 1, dtype=np.bool_), np.ones(n + 1), targets, boxes,
        len(_STATIC_BOXES), F.ARMOR_TABLE, plate, dist,
    )  # fmt: skip
    return np.array(
        [hit_factor(float(dist[j])) * F.ARMOR_TABLE[plate[j], 3] if plate[j] >= 0 else 0.0
         for j in range(n)]
    )  # fmt: skip


class HardBot:
    """The paper's hard bot: "makes two robots siege the robot with the least HP at the best
    candidate points".

    Target: middle's rule (the live enemy with the least HP, ties to the first), so the whole
    team besieges one enemy.

    "Best", from the task's own facts. A robot at a candidate point fires every physics step
    at the nearest valid plate of its target; each step deals hit factor (1.0 below 3 m, 0.5
    to 6 m, 0.2 beyond) × plate multiplier (front 1, side 2, rear 3). Candidate points have
    line of sight to the target by construction, and the abstract action turns the chassis
    toward the target, so its ±0.52 rad firing cone is met at every point: what differs
    between points is the distance (all lie 2.5 m from the target, hit factor 1) and, above
    all, which plate the target shows from there, set by the point's bearing from the
    target's current heading. So a point's value is the damage per step the referee would
    credit a shooter standing there now, :func:`point_damage` (a point behind the target
    scores 3, beside it 2, in front 1); the same points lie outside the target's own firing
    cone, which looks along its heading.

    Two robots besieging attack from different points: the team's live robots take distinct
    points that are not within one robot's ±0.6 m clearance square of each other (the
    candidate filter's rule: a robot standing on one point removes the other), choosing the
    combination with the most damage per step in total; ties (for example either side plate)
    go to the least total travel, then to the first combination in order (robot, point
    index). If no combination is far enough apart, each robot takes its own best point. A
    lone survivor takes its best point. The value is read at the point, from the target's
    heading at this decision; the bot re-decides at every decision, so when the target
    turns, the points follow. No term was tuned against another bot.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp(view, _live(view))
        target = view.poses[view.enemies[e]]
        out = [(e, _nearest_point(view, i, e)) for i in range(len(view.robots))]
        alive = [i for i, r in enumerate(view.robots) if view.alive[r]]
        if not alive:
            return out
        k = view.cands.shape[2]
        pts = view.cands[alive, e]  # (n_alive, k, 2)
        score = point_damage(pts.reshape(-1, 2), target).reshape(len(alive), k)
        travel = np.stack([_travel(view, i, e) for i in alive])
        for i, pick in zip(alive, _best_assignment(pts, score, travel), strict=True):
            out[i] = (e, pick)
        return out


def _best_assignment(pts: np.ndarray, score: np.ndarray, travel: np.ndarray) -> list[int]:
    """One point index per robot: the most total ``score`` among combinations whose points are
    pairwise at least ``ROBOT_CLEARANCE`` apart in x or y, then the least total ``travel``,
    then the first in order; if none is apart, each robot's own best (score, then travel)."""
    n, k = score.shape
    combos = np.stack(np.unravel_index(np.arange(k**n), (k,) * n), axis=1)  # (k^n, n), ordered
    rows = np.arange(n)
    apart = np.ones(len(combos), dtype=bool)
    for a in range(n):
        for b in range(a + 1, n):
            gap = np.abs(pts[a, combos[:, a]] - pts[b, combos[:, b]])
            apart &= (gap >= ROBOT_CLEARANCE).any(axis=1)
    if not apart.any():
        return [int(np.lexsort((travel[i], -score[i]))[0]) for i in range(n)]
    total = score[rows, combos].sum(axis=1)
    cost = travel[rows, combos].sum(axis=1)
    keys = np.lexsort((np.arange(len(combos)), cost, -total))
    best = int(next(j for j in keys if apart[j]))
    return [int(c) for c in combos[best]]


def _uncrowded_pair(view: BotView, a: int, b: int, e: int) -> tuple[int, int] | None:
    """Candidate points for bot robots ``a`` and ``b`` around enemy ``e``: the pair with the
    least total travel that is not closer than :data:`CROWDING` in both x and y (None if
    every pair is)."""
    pa, pb = view.cands[a, e], view.cands[b, e]
    da, db = _travel(view, a, e), _travel(view, b, e)
    apart = (np.abs(pa[:, None] - pb[None]) >= CROWDING).any(axis=2)
    if not apart.any():
        return None
    cost = np.where(apart, da[:, None] + db[None], np.inf)
    x, y = np.unravel_index(int(np.argmin(cost)), cost.shape)
    return int(x), int(y)


class MiddleSpreadBot:
    """``middle_spread``, this project's variant of middle (not the paper's rule): least-HP
    enemy (nearest the team on ties), nearest candidate points that do not crowd.

    Taken literally, "each its own nearest point" often sends both robots to one point or to
    neighbouring ones, so they meet the target from one side and both hit its front plate
    (×1). Here two robots on one target share out the candidate points: the pair with the
    least total travel whose ±0.6 m clearance squares (the candidate filter's) do not overlap,
    that is points at least :data:`CROWDING` apart in x or y; if no pair qualifies, each takes
    its nearest. They then stand apart around the target, so the robot it does not face often
    sees a side plate (×2). The choice looks only at travel, never at the target's heading.
    The spacing was chosen while comparing bots against the easy bot; the figures are in
    docs/contexts.md.
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp_nearest_team(view, _live(view))
        out = [(e, _nearest_point(view, i, e)) for i in range(len(view.robots))]
        alive = [i for i, r in enumerate(view.robots) if view.alive[r]]
        if len(alive) == 2:
            pair = _uncrowded_pair(view, alive[0], alive[1], e)
            if pair is not None:
                out[alive[0]], out[alive[1]] = (e, pair[0]), (e, pair[1])
        return out


class HardFlankBot:
    """``hard_flank``, this project's variant of hard (one reading of "besiege", not the
    paper's "best points"): both robots take the least-HP enemy (nearest the team on ties);
    one holds its front, the other takes its rear.

    A robot's chassis turns toward its own target, so the besieged enemy shows its front plate
    (×1) to the robot it is facing and its side (×2) or rear (×3) plates to anyone behind it.
    Roles per decision: the *holder* is the robot the target faces (the smaller angle off its
    heading) and keeps it facing that way from the nearest candidate point; the *flanker*
    takes the point most behind the target, a little discounted by travel, and never the
    holder's point. A lone survivor flanks.
    """

    TRAVEL = 0.1
    """Score lost per metre to a point; small, so the flanker will walk round the target."""
    CLAIMED = 0.8
    """Points closer than this (m) to the holder's point are left to the holder."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng

    def act(self, view: BotView) -> list[Choice]:
        e = _least_hp_nearest_team(view, _live(view))
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
        score = -np.cos(rel) - self.TRAVEL * _travel(view, i, e)
        if held is not None:
            score = score - 10.0 * (np.hypot(*(pts - held).T) < self.CLAIMED)
        return int(np.argmax(score))


def _off_heading(view: BotView, i: int, target: np.ndarray) -> float:
    """How far (rad) bot robot ``i`` is off the target's heading, as seen from the target."""
    d = view.poses[view.robots[i], :2] - target[:2]
    return abs(float(np.angle(np.exp(1j * (np.arctan2(d[1], d[0]) - target[2])))))


BOTS: dict[str, Callable[[np.random.Generator], Bot]] = {
    "easy": EasyBot,
    "middle": MiddleBot,
    "hard": HardBot,
    "random": RandomBot,
    "middle_spread": MiddleSpreadBot,
    "hard_flank": HardFlankBot,
}
"""Bot classes by level name (the names of ``neuronsmae.protocol.levels.LEVEL_NAMES``)."""

RELEASED_BOTS: dict[int, Callable[[np.random.Generator], Bot]] = {
    0: RandomBot,
    1: ReleasedLevel1Bot,
}
"""Bot classes by the released build's level number (``RELEASED_LEVELS``)."""


def make_bot(level: int | str, rng: np.random.Generator) -> Bot:
    """A bot for ``level``: a released number (0, 1) or a name (one of ``BOTS``), as
    normalised by :func:`neuronsmae.server.contexts.parse_contexts`."""
    if isinstance(level, int):
        return RELEASED_BOTS[level](rng)
    return BOTS[level](rng)
