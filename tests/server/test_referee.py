"""Scripted duels: each shooting rule of the referee, measured by the HP it takes."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.server import Arena
from tests.server.conftest import duel, still

Y = 2.24  # the centre line: only low obstacles (B6, B8, B7) stand on it
STEPS = 20  # physics steps in one decision


def test_distance_bands_over_low_obstacles(arena: Arena) -> None:
    # Muzzle at x + 0.18, front plate of a target facing back (yaw π) at x_t - 0.27.
    for d, factor in ((2.0, 1.0), (4.5, 0.5), (6.9, 0.2)):
        arena.reset()
        lost, _ = duel(arena, (0.35, Y, 0.0), (0.35 + 0.45 + d, Y, np.pi))
        assert lost[2] == pytest.approx(STEPS * factor), d
        assert lost[[0, 1, 3]].sum() == 0.0


def test_plate_multipliers(arena: Arena) -> None:
    for yaw, mult in ((np.pi, 1.0), (np.pi / 2, 2.0), (-np.pi / 2, 2.0), (0.0, 3.0)):
        arena.reset()
        # Side and rear plates sit closer than the front (0.185 / 0.27 m): stay within 3 m.
        lost, _ = duel(arena, (1.0, Y, 0.0), (3.0, Y, yaw))
        assert lost[2] == pytest.approx(STEPS * mult), yaw


def test_bearing_limit(arena: Arena) -> None:
    lost_in, _ = duel(arena, (1.0, Y, 0.45), (3.0, Y, np.pi))
    arena.reset()
    lost_out, _ = duel(arena, (1.0, Y, 0.60), (3.0, Y, np.pi))
    assert lost_in[2] > 0
    assert lost_out[2] == 0


def test_min_range(arena: Arena) -> None:
    # Bodies touching: the muzzle-to-plate distance is below 0.3 m.
    lost, _ = duel(arena, (1.0, Y, 0.0), (1.61, Y, np.pi))
    assert lost[2] == 0


def test_tall_obstacle_blocks(arena: Arena) -> None:
    # B5 spans y 3.35..3.54 at x = 4.04: a target above it is hidden from a shooter below.
    lost, _ = duel(arena, (4.04, 2.6, np.pi / 2), (4.04, 4.1, -np.pi / 2))
    assert lost[2] == 0
    arena.reset()
    lost, _ = duel(arena, (5.0, 2.6, np.pi / 2), (5.0, 4.1, -np.pi / 2))
    assert lost[2] == pytest.approx(STEPS * 1.0)  # the same shot beside B5 lands


def test_coef_scales_red_damage_only(arena: Arena) -> None:
    arena.reset({"coef": 0.5})
    blue_hit, _ = duel(arena, (1.0, Y, 0.0), (3.0, Y, np.pi))
    arena.reset({"coef": 0.5})
    red_hit, _ = duel(arena, (1.0, Y, 0.0), (3.0, Y, np.pi), victim_is_red=False)
    assert blue_hit[2] == pytest.approx(STEPS * 1.0)
    assert red_hit[0] == pytest.approx(STEPS * 0.5)


def test_running_out_of_bullets(arena: Arena) -> None:
    lost, info = duel(arena, (1.0, Y, 0.0), (3.0, Y, np.pi), shooter_bullets=5)
    assert lost[2] == pytest.approx(5.0)
    assert info["bullets"][0] == 0


def test_bullets_spent_per_firing_step(arena: Arena) -> None:
    _, info = duel(arena, (1.0, Y, 0.0), (3.0, Y, np.pi))
    assert info["bullets"][0] == 370 - STEPS
    assert info["damage_dealt"][0] == pytest.approx(STEPS)


def test_annihilation_ends_episode_with_kill_rewards() -> None:
    a = Arena(seed=3, action_space="continuous", n_blue=1, n_red=1, mode="competitive")
    a.reset({"opponent_hp": 10})
    a.place(np.array([(1.0, Y, 0.0), (3.0, Y, np.pi)]), bullets=[370, 0])
    _, rewards, done, info = a.step(still(2))
    assert done and info["winner"] == "blue"
    assert info["kills"] == [1, 0]
    assert info["alive"] == [True, False]
    # 10 HP of damage, one kill, one win.
    assert rewards[0] == pytest.approx(0.01 * 10 + 3 + 20)
    assert info["t"] == 10  # ended mid-decision, on the step the last robot fell
    a.close()


def test_destroyed_robot_stays_as_obstacle() -> None:
    a = Arena(seed=3, action_space="continuous", mode="competitive")
    a.reset({"opponent_hp": 10})
    a.place(
        np.array([(1.0, Y, 0.0), (0.6, 3.9, 0.0), (3.0, Y, np.pi), (7.0, 3.8, 0.0)]),
        bullets=[370, 0, 0, 0],
    )
    a.step(still())
    assert not a.referee.alive[2]
    dead_at = a.poses[2].copy()
    # Drive blue into the wreck for two seconds: it does not move.
    for _ in range(5):
        a.step([np.array([2.0, 0.0, 0.0, 1]), *still(3)])
    np.testing.assert_allclose(a.poses[2], dead_at, atol=1e-9)
    assert a.poses[0, 0] < dead_at[0] - 0.5  # blue is stopped by it (bodies 0.6 m long)
    a.close()


def test_time_limit_decides_by_hp() -> None:
    a = Arena(seed=5, action_space="continuous", episode_steps=40, mode="competitive")
    a.reset()
    a.place(
        np.array([(1.0, Y, 0.0), (0.6, 3.9, 0.0), (3.0, Y, np.pi), (7.5, 0.6, np.pi)]),
        bullets=[370, 0, 0, 0],
    )
    _, _, done, info = a.step(still())
    assert not done
    _, rewards, done, info = a.step(still())
    assert done and info["t"] == 40 and info["winner"] == "blue"
    assert rewards[0] == pytest.approx(0.01 * 20 + 20)
    a.close()


def test_rewards_zero_sum_and_shared_in_competitive_mode() -> None:
    a = Arena(seed=2, action_space="continuous", mode="competitive")
    a.reset()
    a.place(
        np.array([(1.0, Y, 0.0), (0.6, 3.9, 0.0), (3.0, Y, np.pi), (7.5, 0.6, np.pi)]),
        bullets=[370, 0, 0, 0],
    )
    _, rewards, _, _ = a.step(still())
    assert rewards[0] == rewards[1] == pytest.approx(0.2)
    assert rewards[2] == rewards[3] == pytest.approx(-0.2)
    a.close()


def test_sampled_hits_average_to_expected() -> None:
    a = Arena(seed=11, action_space="continuous", hit_mode="sampled", mode="competitive")
    total = 0.0
    for _ in range(10):
        a.reset()
        a.place(
            np.array([(0.35, Y, 0.0), (0.6, 3.9, 0.0), (5.3, Y, np.pi), (7.5, 0.6, np.pi)]),
            bullets=[370, 0, 0, 0],
        )
        hp0 = a.referee.hp[2]
        a.step(still())
        lost = hp0 - a.referee.hp[2]
        assert float(lost).is_integer()  # whole hits only
        total += lost
    assert 0.3 * 200 < total < 0.7 * 200  # p = 0.5 at 4.5 m, 200 shots
    a.close()


def test_both_teams_destroyed_in_one_step_is_a_draw() -> None:
    """Every shot of a step lands together, so both teams can fall at once (docs/reference.md)."""
    from neuronsmae.server.sim.referee import Referee

    ref = Referee(2, 2, np.random.default_rng(0), sampled=False)
    ref.alive[:] = False
    ref.hp[:] = 0.0
    ref.after_kills()
    assert ref.check_end(10, 50) and ref.winner == "draw"
    ref.reset(np.full(4, 600.0), coef=1.0)
    ref.alive[2:] = False
    ref.hp[2:] = 0.0
    ref.after_kills()
    assert ref.check_end(10, 50) and ref.winner == "blue"


@pytest.mark.parametrize(("rule", "winner"), [("hp", "red"), ("damage", "blue")])
def test_time_limit_winner_by_hp_left_or_by_damage_dealt(rule: str, winner: str) -> None:
    """Red starts with 1000 HP; blue shoots red from behind for the one decision there is.
    By HP left (the released build) red wins; by damage dealt (the paper's text) blue does."""
    arena = Arena(seed=0, episode_steps=20, action_space="continuous", time_limit_winner=rule)
    arena.reset({"opponent_hp": 1000.0})
    arena.place(np.array([[2.0, 2.6, 0.0], [0.6, 0.6, 0.0], [3.5, 2.6, 0.0], [7.5, 0.6, 0.0]]))
    _, _, done, info = arena.step([[0, 0, 0, 0], [0, 0, 0, 0]])
    dealt = np.array(info["damage_dealt"])
    assert done and dealt[:2].sum() > dealt[2:].sum() and sum(info["hp"][:2]) < sum(info["hp"][2:])
    assert info["winner"] == winner
    assert info["components"]["win"] == (20.0 if winner == "blue" else -20.0)


def test_an_unknown_time_limit_rule_is_refused_naming_the_choices() -> None:
    from neuronsmae.protocol.errors import InvalidOptionError

    with pytest.raises(InvalidOptionError, match=r"time_limit_winner='kills'.*\('hp', 'damage'\)"):
        Arena(time_limit_winner="kills")
