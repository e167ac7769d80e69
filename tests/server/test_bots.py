"""The rule-based bots' decision rules, each checked on a constructed scene."""

from __future__ import annotations

import numpy as np

from neuronsmae.server.task.bots import BotView, HardBot, MiddleBot

# Enemy 2 sits at (4, 2) facing +x; its four candidate points: front, left, rear, right.
AROUND = np.array([(6.5, 2.0), (4.0, 4.2), (1.5, 2.0), (4.0, 0.2)])
FAR = np.array([(7.5, 3.5)] * 4)


def _view(blue: list, enemy_hp: tuple = (300.0, 600.0), cands=AROUND, alive=None) -> BotView:
    """Bot robots 0, 1 at ``blue``; enemy 2 at (4, 2) yaw 0 and enemy 3 at (7, 4)."""
    poses = np.array([(*blue[0], 0.0), (*blue[1], 0.0), (4.0, 2.0, 0.0), (7.0, 4.0, np.pi)])
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


def test_middle_focuses_the_least_hp_enemy_even_when_the_other_is_nearer() -> None:
    view = _view([(6.8, 3.6), (6.6, 3.8)])
    assert [e for e, _ in MiddleBot(np.random.default_rng(0)).act(view)] == [0, 0]


def test_middle_ties_go_to_the_enemy_nearest_the_team() -> None:
    view = _view([(6.8, 3.6), (6.6, 3.8)], enemy_hp=(600.0, 600.0))
    assert [e for e, _ in MiddleBot(np.random.default_rng(0)).act(view)] == [1, 1]


def test_middle_robots_on_one_target_do_not_share_a_point() -> None:
    # Both robots stand by the front point, each robot's nearest. One keeps it; the other
    # takes the nearest point clear of it, the right one for the robot below the axis.
    view = _view([(6.8, 2.6), (6.8, 1.4)])
    assert MiddleBot(np.random.default_rng(0)).act(view) == [(0, 0), (0, 3)]


def test_middle_shares_points_by_travel_not_robot_order() -> None:
    view = _view([(6.8, 1.4), (6.8, 2.6)])
    assert MiddleBot(np.random.default_rng(0)).act(view) == [(0, 3), (0, 0)]


def test_middle_keeps_nearest_points_that_are_already_apart() -> None:
    view = _view([(6.3, 2.0), (4.0, 4.0)])
    assert MiddleBot(np.random.default_rng(0)).act(view) == [(0, 0), (0, 1)]


def test_middle_points_crowd_within_the_clearance_squares() -> None:
    # (5.5, 3.0) is 1.4 m from the front point but within 1.2 m of it in both x and y, so
    # every pair crowds and each robot falls back to its own nearest point.
    cands = np.array([(6.5, 2.0), (5.5, 3.0), (6.5, 2.0), (6.5, 2.0)])
    view = _view([(6.9, 2.1), (6.9, 1.9)], cands=cands)
    assert MiddleBot(np.random.default_rng(0)).act(view) == [(0, 0), (0, 0)]


def test_middle_lone_survivor_takes_its_nearest_point() -> None:
    view = _view([(6.8, 2.6), (6.8, 1.4)], alive=[True, False, True, True])
    assert MiddleBot(np.random.default_rng(0)).act(view)[0] == (0, 0)


def test_hard_holder_keeps_the_front_and_flanker_takes_the_rear() -> None:
    # Robot 0 is straight ahead of the target (it is being faced): it holds the nearest,
    # front point. Robot 1 stands beside the target: it walks round to the rear point (3×)
    # rather than its nearest, the left side point.
    view = _view([(6.0, 2.0), (4.0, 4.0)])
    assert HardBot(np.random.default_rng(0)).act(view) == [(0, 0), (0, 2)]


def test_hard_roles_follow_the_targets_heading_not_robot_order() -> None:
    view = _view([(4.0, 4.0), (6.0, 2.0)])
    assert HardBot(np.random.default_rng(0)).act(view) == [(0, 2), (0, 0)]


def test_hard_flanker_leaves_the_holders_point() -> None:
    # Only rear points and one rear-left point are valid; the holder's nearest is the rear
    # one, so the flanker takes the rear-left point instead of crowding it.
    cands = np.array([(1.5, 2.0), (1.5, 2.0), (1.5, 2.0), (1.8, 4.3)])
    view = _view([(6.0, 2.0), (5.0, 3.5)], cands=cands)
    assert HardBot(np.random.default_rng(0)).act(view) == [(0, 0), (0, 3)]


def test_hard_lone_survivor_besieges_from_behind() -> None:
    view = _view([(6.0, 2.0), (0.5, 0.5)], alive=[True, False, True, True])
    assert HardBot(np.random.default_rng(0)).act(view)[0] == (0, 2)
