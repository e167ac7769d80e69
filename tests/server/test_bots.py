"""The rule-based bots' decision rules, each checked on a constructed scene, and the mapping
from ``level`` values (released numbers and names) to bots."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.protocol.errors import InvalidContextError, InvalidOptionError
from neuronsmae.protocol.levels import LEVEL_ARGS, LEVEL_CHOICES, LEVEL_NAMES, RELEASED_LEVELS
from neuronsmae.server import Arena
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.contexts import context_table, parse_contexts
from neuronsmae.server.sim.referee import RED
from neuronsmae.server.task.bots import (
    BOTS,
    RELEASED_BOTS,
    BotView,
    EasyBot,
    HardBot,
    HardFlankBot,
    MiddleBot,
    MiddleSpreadBot,
    RandomBot,
    ReleasedLevel1Bot,
    make_bot,
    point_damage,
)


def rng() -> np.random.Generator:
    return np.random.default_rng(0)


# --- this project's variants: enemy 2 at (4, 2) facing +x; points front, left, rear, right.
AROUND = np.array([(6.5, 2.0), (4.0, 4.2), (1.5, 2.0), (4.0, 0.2)])
FAR = np.array([(7.5, 3.5)] * 4)


def _view(blue: list, enemy_hp: tuple = (300.0, 600.0), cands=AROUND, alive=None) -> BotView:
    """Bot robots 0, 1 at ``blue``; enemy 2 at (4, 2) yaw 0 and enemy 3 at (7, 4)."""
    return _scene(blue, (4.0, 2.0, 0.0), enemy_hp, cands, alive)


# --- the paper's and released bots: enemy 2 at (5.5, 2) facing +x on open floor, where no
# tall obstacle hides a plate from any of its points: front, left, rear, right.
TARGET = (5.5, 2.0, 0.0)
OPEN = np.array([(7.5, 2.0), (5.5, 3.8), (3.5, 2.0), (5.5, 0.4)])
FRONT, LEFT, REAR, RIGHT = range(4)


def _scene(
    blue: list, target=TARGET, enemy_hp: tuple = (300.0, 600.0), cands=OPEN, alive=None
) -> BotView:
    """Bot robots 0, 1 at ``blue``; enemy 2 at ``target``, enemy 3 at (7, 4) facing -x.
    ``cands`` are both robots' points around enemy 2; enemy 3's are all at (7.5, 3.5)."""
    poses = np.array([(*blue[0], 0.0), (*blue[1], 0.0), target, (7.0, 4.0, np.pi)])
    per_robot = np.stack([cands, FAR])
    return BotView(
        robots=np.array([0, 1]),
        enemies=np.array([2, 3]),
        poses=poses,
        hp=np.array([600.0, 600.0, *enemy_hp]),
        max_hp=np.full(4, 600.0),
        alive=np.ones(4, dtype=bool) if alive is None else np.array(alive),
        cands=np.stack([per_robot, per_robot]),
        valid=np.ones((2, 2, 4), dtype=bool),
    )


# --- level values ------------------------------------------------------------------------
def test_every_level_has_a_bot() -> None:
    assert set(BOTS) == set(LEVEL_NAMES)
    assert set(RELEASED_BOTS) == set(RELEASED_LEVELS) == {0, 1}
    assert RELEASED_BOTS[0] is BOTS["random"] is RandomBot
    assert RELEASED_BOTS[1] is ReleasedLevel1Bot  # not middle: R2 skips R1's point
    assert BOTS["middle"] is MiddleBot
    assert (BOTS["easy"], BOTS["hard"]) == (EasyBot, HardBot)
    assert (BOTS["middle_spread"], BOTS["hard_flank"]) == (MiddleSpreadBot, HardFlankBot)


@pytest.mark.parametrize(
    ("value", "level", "bot"),
    [
        (0, 0, RandomBot),
        (1, 1, ReleasedLevel1Bot),
        (0.0, 0, RandomBot),
        (1.0, 1, ReleasedLevel1Bot),
        (np.int64(1), 1, ReleasedLevel1Bot),
        ("easy", "easy", EasyBot),
        ("middle", "middle", MiddleBot),
        ("hard", "hard", HardBot),
        ("random", "random", RandomBot),
        ("middle_spread", "middle_spread", MiddleSpreadBot),
        ("hard_flank", "hard_flank", HardFlankBot),
    ],
)
def test_level_values_map_to_bots(value, level, bot) -> None:
    ctx = parse_contexts({"level": value})
    assert ctx.level == level and type(ctx.level) is type(level)
    assert isinstance(make_bot(ctx.level, rng()), bot)


def test_level_defaults_to_easy() -> None:
    assert parse_contexts({}).level == "easy"


@pytest.mark.parametrize("value", [2, -1, 0.5, 2.0, True, False, "0", "1", "2", "Hard", None, [1]])
def test_bad_levels_name_the_key_and_every_valid_value(value) -> None:
    with pytest.raises(InvalidContextError) as err:
        parse_contexts({"level": value})
    text = str(err.value)
    assert "'level'" in text and "[0, 1]" in text
    for name in LEVEL_NAMES:
        assert repr(name) in text


def test_bad_level_messages_say_which_names_to_use() -> None:
    with pytest.raises(InvalidContextError, match=r"no level 2.*'hard'"):
        parse_contexts({"level": 2})
    with pytest.raises(InvalidContextError, match="the number 1, not a string"):
        parse_contexts({"level": "1"})


def test_context_table_advertises_exactly_what_reset_accepts() -> None:
    (row,) = [r for r in context_table() if r["key"] == "level"]
    assert row["choices"] == list(LEVEL_CHOICES) == [0, 1, *LEVEL_NAMES]
    assert [type(c) for c in row["choices"][:2]] == [int, int]
    for choice in row["choices"]:
        assert parse_contexts({"level": choice}).level == choice
    assert parse_contexts({"level": row["default"]}).level == row["default"]


def test_released_scripts_contexts_give_the_released_bots() -> None:
    arena = Arena(seed=1)
    try:
        arena.reset({"coef": 0.5, "level": 1.0})
        assert arena.context.coef == 0.5 and arena.context.level == 1
        assert type(arena.bots[RED]) is ReleasedLevel1Bot
        arena.reset({"VK1": 0.0375, "level": 0})
        assert arena.context.blue_dynamics["vk1"] == 0.0375 and arena.context.level == 0
        assert type(arena.bots[RED]) is RandomBot
        assert arena.bots[RED].rng is arena.rng  # draws from the arena's RNG
        assert arena.context.to_dict()["level"] == 0  # recorded as given: replays re-parse it
    finally:
        arena.close()


@pytest.mark.parametrize("value", [0, 1, 1.0, *LEVEL_NAMES])
def test_blue_level_option_takes_the_same_values(value) -> None:
    assert ArenaConfig(blue_level=value).blue_level == parse_contexts({"level": value}).level


@pytest.mark.parametrize("value", [2, "0", True, "expert"])
def test_bad_blue_level_option_lists_the_valid_values(value) -> None:
    with pytest.raises(InvalidOptionError, match=r"blue_level.*\[0, 1\].*'hard_flank'"):
        ArenaConfig(blue_level=value)


def test_command_line_levels() -> None:
    from neuronsmae.server.tools.demo import main as demo

    assert tuple(LEVEL_ARGS) == ("0", "1", *LEVEL_NAMES)
    assert demo(["--blue", "hard_flank", "--red", "1", "--seed", "3"]) == 0


# --- released level 0 / random -------------------------------------------------------------
def test_random_picks_only_live_targets_and_every_point() -> None:
    view = _scene([(7.0, 1.0), (4.0, 3.5)], alive=[True, True, False, True])
    bot = RandomBot(rng())
    picks = [c for _ in range(100) for c in bot.act(view)]
    assert {e for e, _ in picks} == {1}
    assert {p for _, p in picks} == {0, 1, 2, 3}


def test_random_redraws_from_its_rng_reproducibly() -> None:
    view = _scene([(7.0, 1.0), (4.0, 3.5)])
    a, b = RandomBot(np.random.default_rng(5)), RandomBot(np.random.default_rng(5))
    seq_a = [a.act(view) for _ in range(20)]
    assert seq_a == [b.act(view) for _ in range(20)]
    assert len({tuple(s) for s in seq_a}) > 1  # redrawn each decision
    other = RandomBot(np.random.default_rng(6))
    assert [other.act(view) for _ in range(20)] != seq_a


def test_released_level_0_episodes_are_reproducible_per_seed() -> None:
    def play(seed: int) -> list:
        arena = Arena(seed=seed)
        try:
            arena.reset({"level": 0})
            for _ in range(5):
                arena.step([0, 0])
            return arena.get_state().tolist()
        finally:
            arena.close()

    assert play(7) == play(7)
    assert play(7) != play(8)


# --- released level 1 and the paper's middle ------------------------------------------------
def test_middle_focuses_the_least_hp_enemy_even_when_the_other_is_nearer() -> None:
    view = _scene([(6.8, 3.6), (6.6, 3.8)])
    assert [e for e, _ in MiddleBot(rng()).act(view)] == [0, 0]
    view = _scene([(6.0, 1.0), (5.0, 1.0)], enemy_hp=(600.0, 599.0))
    assert [e for e, _ in MiddleBot(rng()).act(view)] == [1, 1]


def test_middle_ties_go_to_the_first_enemy() -> None:
    # Equal HP (as at the start): a plain argmin takes enemy 0 although enemy 1 is nearer.
    view = _scene([(6.8, 3.6), (6.6, 3.8)], enemy_hp=(600.0, 600.0))
    assert [e for e, _ in MiddleBot(rng()).act(view)] == [0, 0]


def test_middle_robots_each_take_their_own_nearest_point_even_a_shared_one() -> None:
    view = _scene([(7.2, 2.6), (7.2, 1.4)])
    assert MiddleBot(rng()).act(view) == [(0, FRONT), (0, FRONT)]
    view = _scene([(7.2, 2.6), (4.0, 1.0)])
    assert MiddleBot(rng()).act(view) == [(0, FRONT), (0, REAR)]


def test_middle_skips_a_dead_enemy() -> None:
    view = _scene([(6.8, 3.6), (6.6, 3.8)], alive=[True, True, False, True])
    assert [e for e, _ in MiddleBot(rng()).act(view)] == [1, 1]


# --- the paper's easy -----------------------------------------------------------------------
def test_easy_each_robot_attacks_its_nearest_enemy_from_its_nearest_point() -> None:
    # Robot 0 is near enemy 2 (the least HP), robot 1 near enemy 3: HP does not matter.
    view = _scene([(7.2, 1.4), (6.8, 3.6)], enemy_hp=(600.0, 100.0))
    assert EasyBot(rng()).act(view) == [(0, FRONT), (1, 0)]
    view = _scene([(3.8, 1.8), (5.3, 0.6)])
    assert EasyBot(rng()).act(view) == [(0, REAR), (0, RIGHT)]


def test_easy_skips_a_dead_enemy() -> None:
    view = _scene([(7.2, 1.4), (6.8, 3.6)], alive=[True, True, True, False])
    assert [e for e, _ in EasyBot(rng()).act(view)] == [0, 0]


# --- the paper's hard -----------------------------------------------------------------------
def test_point_damage_is_the_referees_hit_factor_times_plate() -> None:
    target = np.array(TARGET)
    assert point_damage(OPEN, target).tolist() == [1.0, 2.0, 3.0, 2.0]  # front, side, rear
    assert point_damage(np.array([(2.0, 2.0)]), target).tolist() == [1.5]  # 3.5 m: × 0.5
    # Turned round, the target shows its rear plate to the former front point.
    turned = np.array([5.5, 2.0, np.pi])
    assert point_damage(OPEN, turned).tolist() == [3.0, 2.0, 1.0, 2.0]
    # Below the tall obstacle B4 (x 3.55..4.53, y 0.95..1.13) no plate can be hit.
    assert point_damage(np.array([(3.8, 0.8)]), target).tolist() == [0.0]


def test_hard_takes_the_rear_and_a_side_not_the_nearest_points() -> None:
    # Robot 0's nearest point is the front (×1), robot 1's the left side. The best pair is
    # the rear (×3) and a side (×2); of the two such pairs, the one with less travel.
    view = _scene([(7.0, 1.0), (4.0, 3.5)])
    assert MiddleBot(rng()).act(view) == [(0, FRONT), (0, LEFT)]
    assert HardBot(rng()).act(view) == [(0, RIGHT), (0, REAR)]


def test_hard_points_follow_robot_positions_not_robot_order() -> None:
    view = _scene([(4.0, 3.5), (7.0, 1.0)])
    assert HardBot(rng()).act(view) == [(0, REAR), (0, RIGHT)]


def test_hard_points_follow_the_targets_heading() -> None:
    view = _scene([(7.0, 1.0), (4.0, 3.5)], target=(5.5, 2.0, np.pi))
    assert HardBot(rng()).act(view) == [(0, FRONT), (0, LEFT)]  # the front point is now behind


def test_hard_sends_both_robots_behind_when_two_rear_points_are_apart() -> None:
    cands = np.array([(7.5, 2.0), (3.5, 2.0), (3.8, 3.2), (5.5, 3.8)])
    assert point_damage(cands, np.array(TARGET)).tolist() == [1.0, 3.0, 3.0, 2.0]
    view = _scene([(7.0, 1.0), (6.0, 3.5)], cands=cands)
    assert HardBot(rng()).act(view) == [(0, 1), (0, 2)]


def test_hard_robots_do_not_share_a_point_or_crowd_one() -> None:
    # Two rear points within one robot's ±0.6 m clearance square: one robot takes the rear,
    # the other a side; never both the same point.
    cands = np.array([(7.5, 2.0), (3.5, 2.0), (3.8, 2.4), (5.5, 3.8)])
    assert point_damage(cands, np.array(TARGET)).tolist() == [1.0, 3.0, 3.0, 2.0]
    view = _scene([(3.6, 2.1), (3.7, 2.3)], cands=cands)
    picks = [p for _, p in HardBot(rng()).act(view)]
    assert sorted(picks) in ([1, 3], [2, 3])
    assert HardBot(rng()).act(view) == [(0, 1), (0, 3)]  # the pair with the least travel


def test_hard_lone_survivor_takes_the_best_point() -> None:
    view = _scene([(7.0, 1.0), (4.0, 3.5)], alive=[True, False, True, True])
    assert HardBot(rng()).act(view)[0] == (0, REAR)


def test_hard_besieges_the_least_hp_enemy_ties_to_the_first() -> None:
    view = _scene([(6.8, 3.6), (6.6, 3.8)], enemy_hp=(600.0, 600.0))
    assert [e for e, _ in HardBot(rng()).act(view)] == [0, 0]
    view = _scene([(7.0, 1.0), (4.0, 3.5)], enemy_hp=(600.0, 500.0))
    assert [e for e, _ in HardBot(rng()).act(view)] == [1, 1]


# --- this project's variants ----------------------------------------------------------------
def test_middle_spread_focuses_the_least_hp_enemy_even_when_the_other_is_nearer() -> None:
    view = _view([(6.8, 3.6), (6.6, 3.8)])
    assert [e for e, _ in MiddleSpreadBot(rng()).act(view)] == [0, 0]


def test_middle_spread_ties_go_to_the_enemy_nearest_the_team() -> None:
    view = _view([(6.8, 3.6), (6.6, 3.8)], enemy_hp=(600.0, 600.0))
    assert [e for e, _ in MiddleSpreadBot(rng()).act(view)] == [1, 1]


def test_middle_spread_robots_on_one_target_do_not_share_a_point() -> None:
    # Both robots stand by the front point, each robot's nearest. One keeps it; the other
    # takes the nearest point clear of it, the right one for the robot below the axis.
    view = _view([(6.8, 2.6), (6.8, 1.4)])
    assert MiddleSpreadBot(rng()).act(view) == [(0, 0), (0, 3)]


def test_middle_spread_shares_points_by_travel_not_robot_order() -> None:
    view = _view([(6.8, 1.4), (6.8, 2.6)])
    assert MiddleSpreadBot(rng()).act(view) == [(0, 3), (0, 0)]


def test_middle_spread_keeps_nearest_points_that_are_already_apart() -> None:
    view = _view([(6.3, 2.0), (4.0, 4.0)])
    assert MiddleSpreadBot(rng()).act(view) == [(0, 0), (0, 1)]


def test_middle_spread_points_crowd_within_the_clearance_squares() -> None:
    # (5.5, 3.0) is 1.4 m from the front point but within 1.2 m of it in both x and y, so
    # every pair crowds and each robot falls back to its own nearest point.
    cands = np.array([(6.5, 2.0), (5.5, 3.0), (6.5, 2.0), (6.5, 2.0)])
    view = _view([(6.9, 2.1), (6.9, 1.9)], cands=cands)
    assert MiddleSpreadBot(rng()).act(view) == [(0, 0), (0, 0)]


def test_middle_spread_lone_survivor_takes_its_nearest_point() -> None:
    view = _view([(6.8, 2.6), (6.8, 1.4)], alive=[True, False, True, True])
    assert MiddleSpreadBot(rng()).act(view)[0] == (0, 0)


def test_hard_flank_holder_keeps_the_front_and_flanker_takes_the_rear() -> None:
    # Robot 0 is straight ahead of the target (it is being faced): it holds the nearest,
    # front point. Robot 1 stands beside the target: it walks round to the rear point (3×)
    # rather than its nearest, the left side point.
    view = _view([(6.0, 2.0), (4.0, 4.0)])
    assert HardFlankBot(rng()).act(view) == [(0, 0), (0, 2)]


def test_hard_flank_roles_follow_the_targets_heading_not_robot_order() -> None:
    view = _view([(4.0, 4.0), (6.0, 2.0)])
    assert HardFlankBot(rng()).act(view) == [(0, 2), (0, 0)]


def test_hard_flank_flanker_leaves_the_holders_point() -> None:
    # Only rear points and one rear-left point are valid; the holder's nearest is the rear
    # one, so the flanker takes the rear-left point instead of crowding it.
    cands = np.array([(1.5, 2.0), (1.5, 2.0), (1.5, 2.0), (1.8, 4.3)])
    view = _view([(6.0, 2.0), (5.0, 3.5)], cands=cands)
    assert HardFlankBot(rng()).act(view) == [(0, 0), (0, 3)]


def test_hard_flank_lone_survivor_besieges_from_behind() -> None:
    view = _view([(6.0, 2.0), (0.5, 0.5)], alive=[True, False, True, True])
    assert HardFlankBot(rng()).act(view)[0] == (0, 2)


# --- the released level 1 -----------------------------------------------------------------
def test_released_level_1_gives_r2_its_nearest_point_other_than_r1s() -> None:
    """Both robots are nearest the rear point: middle sends both there, the released level 1
    sends R2 to its next nearest (the build's managed code)."""
    view = _scene([(3.0, 2.1), (3.2, 1.9)])
    assert MiddleBot(rng()).act(view) == [(0, REAR), (0, REAR)]
    r1, r2 = ReleasedLevel1Bot(rng()).act(view)
    assert r1 == (0, REAR) and r2[0] == 0 and r2[1] != REAR
    travel = np.hypot(*(OPEN - (3.2, 1.9)).T)
    travel[REAR] = np.inf
    assert r2[1] == int(np.argmin(travel))


def test_released_level_1_targets_the_least_hp_enemy_and_a_dead_r1_takes_no_point() -> None:
    view = _scene([(3.0, 2.1), (3.2, 1.9)], enemy_hp=(600.0, 300.0), alive=[False, True, 1, 1])
    assert [e for e, _ in ReleasedLevel1Bot(rng()).act(view)] == [1, 1]  # enemy 3: less HP
    view = _scene([(3.0, 2.1), (3.2, 1.9)], alive=[False, True, True, True])
    assert ReleasedLevel1Bot(rng()).act(view)[1] == (0, REAR)  # R1 destroyed: R2 is free
