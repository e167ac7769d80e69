"""RMUA zones: dealt in symmetric pairs, triggered by the first robot on them, effects applied."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.server import Arena
from neuronsmae.server.sim import field as F
from neuronsmae.server.sim.zones import EFFECT_PAIRS
from tests.server.conftest import duel, still


def _on_zones(seed: int) -> tuple[Arena, dict]:
    a = Arena(seed=seed, mode="competitive", action_space="continuous", zones=True)
    a.reset()
    a.referee.hp[:] = 300.0
    # Everyone faces a wall and has no bullets: only zone effects change HP and ammunition.
    poses = np.array(
        [(*F.ZONES["F1"], np.pi), (*F.ZONES["F2"], np.pi), (*F.ZONES["F4"], 0.0), (7.5, 3.9, 0.0)]
    )
    a.place(poses, bullets=[0, 0, 0, 0])
    _, _, _, info = a.step(still())
    return a, info


@pytest.mark.parametrize("seed", range(6))
def test_zones_dealt_in_pairs_and_applied(seed: int) -> None:
    a, info = _on_zones(seed)
    log = {zone: (effect, robot) for _, zone, effect, robot in info["zone_log"]}
    assert set(log) == {"F1", "F2", "F4"}
    # F1 and F4 are a pair: they hold the two halves of one effect pair.
    assert tuple(sorted((log["F1"][0], log["F4"][0]))) in {tuple(sorted(p)) for p in EFFECT_PAIRS}
    hp, bullets = np.array(info["hp"]), np.array(info["bullets"])
    effects = [e for e, _ in log.values()]
    for team, robots in (("blue", slice(0, 2)), ("red", slice(2, 4))):
        assert (hp[robots] == (500.0 if f"hp_{team}" in effects else 300.0)).all()
        assert (bullets[robots] == (100 if f"ammo_{team}" in effects else 0)).all()
    for effect, robot in log.values():
        if effect == "no_move":
            assert a.zones.frozen(a.t)[robot]
        if effect == "no_shoot":
            assert a.zones.silenced(a.t)[robot]
    a.close()


def test_frozen_robot_does_not_move_and_zone_is_spent() -> None:
    for seed in range(20):
        a, info = _on_zones(seed)
        robots = [r for _, _, e, r in info["zone_log"] if e == "no_move"]
        if not robots:
            a.close()
            continue
        r = robots[0]
        before = a.poses[r].copy()
        acts = still()
        acts[r] = np.array([2.0, 0.0, 0.0, 0])
        _, _, _, info = a.step(acts)
        np.testing.assert_allclose(a.poses[r, :2], before[:2], atol=1e-6)
        assert len(info["zone_log"]) == 3  # standing on spent zones triggers nothing more
        a.close()
        return
    pytest.fail("no seed dealt a no-move zone onto F1, F2 or F4")


def test_silenced_robot_deals_no_damage_where_it_otherwise_would() -> None:
    """A robot that took a no-shoot zone, put in a duel it wins without the zone (the same
    duel in a zone-less arena), hits nothing while silenced."""
    for seed in range(30):
        a, info = _on_zones(seed)
        robots = [r for _, _, e, r in info["zone_log"] if e == "no_shoot" and r in (0, 2)]
        if not robots:
            a.close()
            continue
        shooter_is_blue = robots[0] == 0
        assert a.zones.silenced(a.t)[robots[0]]
        lanes = ((1.0, 2.24, 0.0), (3.0, 2.24, np.pi))  # the centre line, 2 m apart
        silenced, _ = duel(a, *lanes, victim_is_red=shooter_is_blue)
        a.close()
        plain = Arena(seed=seed, mode="competitive", action_space="continuous")
        plain.reset()
        armed, _ = duel(plain, *lanes, victim_is_red=shooter_is_blue)
        plain.close()
        victim = 2 if shooter_is_blue else 0
        assert armed[victim] > 0 and silenced[victim] == 0
        return
    pytest.fail("no seed dealt a no-shoot zone onto F1 or F4")


def test_zones_off_by_default() -> None:
    a = Arena(seed=1)
    a.reset()
    _, _, _, info = a.step([0, 0])
    assert "zones" not in info
    a.close()


@pytest.mark.parametrize("episode_steps", [1000, 3001, 6001])
def test_observations_stay_in_range_with_every_ammunition_bonus(episode_steps: int) -> None:
    """Bullets are divided by the most a robot can hold in the episode: 370, plus 100 per
    refresh (0, 60, 120 s) the episode lasts into. By the 370 alone, a robot that took a
    bonus before shooting read 1.43 where the layout promises [-1, 1]."""
    cap = 370.0 + 100.0 * {1000: 1, 3001: 2, 6001: 3}[episode_steps]
    for seed in range(6):
        a = Arena(seed=seed, zones=True, episode_steps=episode_steps)
        a.reset()
        assert (a.referee.max_bullets == cap).all()
        zones = F.ZONES
        a.place(np.array([[*zones["F1"], 0.0], [*zones["F2"], 0.0], [*zones["F4"], np.pi],
                          [*zones["F5"], np.pi]]))  # fmt: skip
        obs, _, _, info = a.step([0, 0])
        assert max(float(np.abs(o).max()) for o in obs) <= 1.0, info["zone_log"]
        assert float(np.abs(a.get_state()).max()) <= 1.0
        assert a.referee.bullets.max() <= cap
    assert Arena(seed=0).referee.max_bullets.max() == 370.0  # without zones: as released
