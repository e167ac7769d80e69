"""RMUA bonus and penalty zones (an option; the released build had them do nothing).

At 0, 60 and 120 s each centrally symmetric zone pair {F1, F4}, {F2, F5}, {F3, F6} is dealt
one effect pair: HP +200 for blue / for red, ammunition +100 for blue / for red, or
no-shooting / no-moving for 10 s. The first robot to drive onto an active zone triggers it
(whatever its team: a robot that crosses the other team's bonus zone hands it to them) and
the zone stays spent until the next refresh. HP is capped at each robot's starting HP.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from neuronsmae.server.sim import field as F

REFRESH_S = (0.0, 60.0, 120.0)
PENALTY_S = 10.0
HP_BONUS = 200.0
AMMO_BONUS = 100.0
EFFECT_PAIRS = (("hp_blue", "hp_red"), ("ammo_blue", "ammo_red"), ("no_shoot", "no_move"))
ZONE_NAMES = tuple(F.ZONES)


@dataclass
class ZoneState:
    """Active effects and per-robot penalty timers."""

    effects: dict[str, str] = field(default_factory=dict)
    """Zone name → effect, for zones not yet triggered since the last refresh."""
    no_shoot_until: np.ndarray = field(default_factory=lambda: np.zeros(0))
    no_move_until: np.ndarray = field(default_factory=lambda: np.zeros(0))
    log: list[tuple[float, str, str, int]] = field(default_factory=list)
    """(time s, zone, effect, robot) for every trigger, for info and replays."""


class Zones:
    """Deals, triggers and applies the zone effects; owned by one arena."""

    def __init__(self, rng: np.random.Generator, n_blue: int, n_robots: int) -> None:
        self.rng = rng
        self.n_blue = n_blue
        self.n = n_robots
        hx, hy = F.ZONE_SIZE_RMUA[0] / 2, F.ZONE_SIZE_RMUA[1] / 2
        centres = np.array([F.ZONES[z] for z in ZONE_NAMES])
        half = np.array([hx, hy])
        self.lo = centres - half
        self.hi = centres + half
        self.state = ZoneState()

    @staticmethod
    def ammo_capacity(episode_steps: int) -> float:
        """The most bullets the ammunition bonuses can add to one robot in an episode of
        ``episode_steps`` physics steps (one bonus per refresh it lasts into)."""
        refreshes = sum(r < episode_steps * F.PHYSICS_DT for r in REFRESH_S)
        return AMMO_BONUS * refreshes

    def reset(self) -> None:
        """Clear timers; effects are dealt at the first :meth:`update` (t = 0)."""
        self.state = ZoneState(no_shoot_until=np.zeros(self.n), no_move_until=np.zeros(self.n))

    def _deal(self) -> None:
        order = self.rng.permutation(len(EFFECT_PAIRS))
        effects = {}
        for (za, zb), k in zip(F.ZONE_PAIRS, order, strict=True):
            pair = EFFECT_PAIRS[k]
            if self.rng.random() < 0.5:
                pair = pair[::-1]
            effects[za], effects[zb] = pair
        self.state.effects = effects

    def update(
        self,
        t_steps: int,
        poses: np.ndarray,
        alive: np.ndarray,
        hp: np.ndarray,
        max_hp: np.ndarray,
        bullets: np.ndarray,
    ) -> None:
        """Refresh on schedule, then trigger zones under live robots; edits hp and bullets."""
        now = t_steps * F.PHYSICS_DT
        if any(abs(now - r) < F.PHYSICS_DT / 2 for r in REFRESH_S):
            self._deal()
        if not self.state.effects:
            return
        xy = poses[:, :2]
        inside = ((xy[:, None] >= self.lo[None]) & (xy[:, None] <= self.hi[None])).all(-1)
        for robot, zone in zip(*np.nonzero(inside & alive[:, None]), strict=True):
            name = ZONE_NAMES[zone]
            effect = self.state.effects.pop(name, None)
            if effect is not None:
                self._apply(effect, int(robot), now, hp, max_hp, bullets, alive)
                self.state.log.append((now, name, effect, int(robot)))

    def _apply(
        self,
        effect: str,
        robot: int,
        now: float,
        hp: np.ndarray,
        max_hp: np.ndarray,
        bullets: np.ndarray,
        alive: np.ndarray,
    ) -> None:
        team = slice(0, self.n_blue) if effect.endswith("blue") else slice(self.n_blue, self.n)
        if effect.startswith("hp_"):
            live = alive[team]
            hp[team][live] = np.minimum(hp[team][live] + HP_BONUS, max_hp[team][live])
        elif effect.startswith("ammo_"):
            bullets[team][alive[team]] += AMMO_BONUS
        elif effect == "no_shoot":
            self.state.no_shoot_until[robot] = now + PENALTY_S
        else:
            self.state.no_move_until[robot] = now + PENALTY_S

    def silenced(self, t_steps: int) -> np.ndarray:
        """(N,) bool: robots under a no-shooting penalty now."""
        return self.state.no_shoot_until > t_steps * F.PHYSICS_DT

    def frozen(self, t_steps: int) -> np.ndarray:
        """(N,) bool: robots under a no-moving penalty now."""
        return self.state.no_move_until > t_steps * F.PHYSICS_DT

    def info(self) -> dict[str, object]:
        """Effects still on offer and every trigger so far."""
        return {
            "zones": dict(self.state.effects),
            "zone_log": [list(entry) for entry in self.state.log],
        }
