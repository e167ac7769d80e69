"""Action spaces: decoding, masks, bad-action errors, and the abstract planner end to end."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.protocol.errors import InvalidActionError
from neuronsmae.server import Arena

OPEN = np.array([(1.0, 1.9, 0.0), (0.6, 3.9, 0.0), (7.4, 3.9, np.pi), (7.5, 0.6, np.pi)])


@pytest.mark.parametrize(
    ("space", "actions", "needle"),
    [
        ("abstract", [0], "expected 2 actions"),
        ("abstract", [0, 8], r"agent 1.*\[0, 7\]"),
        ("abstract", [0, -1], "agent 1"),
        ("abstract", [0, "3"], "agent 1: action must be an integer"),
        ("abstract", [0, 1.5], "agent 1"),
        ("abstract", "01", "sequence"),
        ("discrete", [10, 0], r"agent 0.*\[0, 9\]"),
        ("continuous", [[0, 0, 0, 0], [0, 0, 0]], r"agent 1.*shape \(4,\)"),
        ("continuous", [[0, 0, 0, 0], [2.5, 0, 0, 0]], r"agent 1: vx=2.5 is outside \[-2.0, 2.0\]"),
        ("continuous", [[0, 0, 1.8, 0], [0, 0, 0, 0]], r"agent 0: omega=1.8.*1.75"),
        ("continuous", [[0, np.nan, 0, 0], [0, 0, 0, 0]], "agent 0: action has NaN"),
        ("continuous", [[0, 0, 0, np.inf], [0, 0, 0, 0]], "agent 0: action has NaN or infinite"),
        ("continuous", [[0, 0, 0, 2], [0, 0, 0, 0]], r"agent 0: target=2.0.*\[0, 1\]"),
        ("continuous", [[0, 0, 0, 0.5], [0, 0, 0, 0]], "target"),
        ("continuous", [["a", 0, 0, 0], [0, 0, 0, 0]], "agent 0"),
    ],
)
def test_bad_actions_raise_naming_agent_and_bound(space: str, actions, needle: str) -> None:
    a = Arena(seed=1, action_space=space)
    a.reset()
    before = a.get_obs()
    with pytest.raises(InvalidActionError, match=needle) as err:
        a.step(actions)
    assert isinstance(err.value, ValueError)
    # A rejected action never advances or corrupts the episode.
    assert a.t == 0
    np.testing.assert_array_equal(np.stack(a.get_obs()), np.stack(before))
    a.close()


def test_clip_option_clips_instead() -> None:
    """Out-of-bound motions play exactly as the bounds they are clipped to."""
    from neuronsmae.protocol.env_info import V_MAX, W_MAX

    clipped, bounded = (Arena(seed=1, action_space="continuous", clip_actions=True)
                        for _ in range(2))  # fmt: skip
    try:
        clipped.reset()
        bounded.reset()
        for _ in range(3):
            clipped.step([[9.0, -9.0, 5.0, 1], [0, 0, -7.0, 0]])
            bounded.step([[V_MAX, -V_MAX, W_MAX, 1], [0, 0, -W_MAX, 0]])
        np.testing.assert_array_equal(clipped.get_state(), bounded.get_state())
        moved = Arena(seed=1, action_space="continuous", clip_actions=True)
        moved.reset()
        for _ in range(3):
            moved.step([[0, 0, 0, 1], [0, 0, 0, 0]])  # the same targets, standing still
        assert not np.array_equal(clipped.get_state(), moved.get_state())  # the motion acted
        moved.close()
    finally:
        clipped.close()
        bounded.close()


@pytest.mark.parametrize("target", [0.5, -3, 7, 1e300, True, "1"])
def test_clip_option_never_clips_the_target(target) -> None:
    """``clip_actions`` clips motion commands; a target names an enemy, so one that names
    none (a fraction, out of range, a bool or a string) is refused even so."""
    a = Arena(seed=1, action_space="continuous", clip_actions=True)
    a.reset()
    with pytest.raises(InvalidActionError, match="agent 0"):
        a.step([[9.0, 0, 0, target], [0, 0, 0, 0]])
    a.close()


@pytest.mark.parametrize(
    "row", [["1", 0, 0, 0], [b"1", 0, 0, 0], [True, 0, 0, 0], np.array(["1", "0", "0", "0"])]
)
def test_continuous_actions_must_be_numbers(row) -> None:
    """Strings, bytes and bools are refused as discrete actions are, though NumPy would
    convert them; NumPy numbers and tuples of them are accepted."""
    a = Arena(seed=1, action_space="continuous")
    a.reset()
    with pytest.raises(InvalidActionError, match="agent 0: continuous action must be 4 numbers"):
        a.step([row, [0, 1, 0, 1]])
    a.step([(np.float32(0.5), np.int64(0), 0.0, 1), np.array([0, 1, 0, 1])])
    a.close()


@pytest.mark.parametrize("actions", [{0: 1, 1: 1}, {0, 1}, frozenset({0, 1}), "01", b"01", None, 3])
def test_actions_must_be_a_sequence(actions) -> None:
    """A mapping (its keys), a set (no order), a string (its characters) or a scalar is not
    a joint action."""
    a = Arena(seed=1)
    a.reset()
    with pytest.raises(InvalidActionError, match="actions must be a sequence of 2"):
        a.step(actions)
    a.close()


def test_a_bot_driven_teams_actions_are_not_checked() -> None:
    """Competitive mode, ``bot_team="red"``: red's entries are ignored, so not checked (the
    count still is), as a vector ignores the rows of arenas that do not step."""
    a = Arena(seed=1, mode="competitive")
    a.reset({"bot_team": "red"})
    a.step([0, 1, 99, "x"])
    with pytest.raises(InvalidActionError, match="agent 0"):
        a.step([99, 1, 0, 0])
    with pytest.raises(InvalidActionError, match="expected 4 actions"):
        a.step([0, 1])
    a.reset({"bot_team": "none"})
    with pytest.raises(InvalidActionError, match="agent 2"):
        a.step([0, 1, 99, 0])
    a.close()


def test_masks_for_dead_robots_and_dead_enemies() -> None:
    a = Arena(seed=1, action_space="abstract", mode="competitive")
    a.reset()
    a.place(OPEN)
    a.referee.alive[1] = False  # blue_1 destroyed
    a.referee.alive[3] = False  # red_1 destroyed
    m = a.get_avail_actions()
    assert m[1].tolist() == [1, 0, 0, 0, 0, 0, 0, 0]  # only the no-op
    assert m[0][:4].any() and not m[0][4:].any()  # cannot target red_1
    assert m[2][:4].any() and not m[2][4:].any()  # red_0 cannot target dead blue_1
    for mask in m:
        assert mask.dtype == np.int8
    a.close()


def test_discrete_moves_in_body_frame() -> None:
    a = Arena(seed=1, action_space="discrete", mode="competitive")
    a.reset()
    # blue_0 faces +y: "right" (move 4) goes to +x; it targets red_0 straight ahead.
    a.place(
        np.array(
            [(2.5, 1.0, np.pi / 2), (0.6, 3.9, 0.0), (2.5, 3.0, -np.pi / 2), (7.5, 0.6, np.pi)]
        ),
        bullets=[0, 0, 0, 0],
    )
    for _ in range(8):
        a.step([4, 0, 0, 0])
    assert a.poses[0, 0] > 2.5 + 0.5
    assert abs(a.poses[0, 1] - 1.0) < 0.15
    a.close()


def test_discrete_released_period_is_five_steps() -> None:
    a = Arena(seed=1, action_space="discrete")
    a.reset()
    _, _, _, info = a.step([0, 0])
    assert info["t"] == 5 and a.get_env_info()["episode_limit"] == 200
    a.close()


def test_auto_turn_faces_the_target() -> None:
    a = Arena(seed=1, action_space="discrete", mode="competitive")
    a.reset()
    a.place(
        np.array([(3.0, 1.9, 0.0), (0.6, 3.9, 0.0), (3.0, 3.2, 0.0), (7.5, 0.6, np.pi)]),
        bullets=[0, 0, 0, 0],
    )
    for _ in range(40):  # 4 s of "stop" aimed at red_0 straight above (ω = heading error)
        a.step([0, 0, 0, 0])
    assert a.poses[0, 2] == pytest.approx(np.pi / 2, abs=0.1)
    a.close()


def test_abstract_action_drives_to_chosen_candidate_point() -> None:
    a = Arena(seed=1, action_space="abstract", mode="competitive")
    a.reset()
    a.place(
        np.array([(1.0, 1.0, 0.0), (0.6, 3.9, 0.0), (5.0, 2.8, np.pi), (7.5, 0.6, np.pi)]),
        bullets=[0, 0, 0, 0],
    )
    goal = a.cands[0, 0, 2].copy()  # blue_0's third point around red_0
    for _ in range(12):
        a.step([2, 0, 0, 0])
        a.place(
            np.concatenate([a.poses[:2], [(5.0, 2.8, np.pi), (7.5, 0.6, np.pi)]]),
            bullets=[0, 0, 0, 0],
        )  # hold red still so the point stays put
        if np.hypot(*(a.poses[0, :2] - goal)) < 0.2:
            break
    assert np.hypot(*(a.poses[0, :2] - goal)) < 0.2
    a.close()


def test_candidate_points_in_obs_are_deterministic() -> None:
    a, b = Arena(seed=5), Arena(seed=5)
    oa, ob = a.reset(), b.reset()
    np.testing.assert_array_equal(oa[0][12:28], ob[0][12:28])
    assert np.abs(oa[0][12:28]).max() <= 1.0
    a.close()
    b.close()
