"""The in-process arena: dynamics contexts, collisions, episode ends, determinism, contexts."""

from __future__ import annotations

import hashlib
import re
import subprocess
import sys

import numpy as np
import pytest

from neuronsmae.protocol.errors import InvalidContextError, InvalidOptionError, ResetNeededError
from neuronsmae.server import Arena
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.sim import field as F
from tests.server.conftest import still

START = np.array([(1.0, 1.9, 0.0), (0.6, 3.9, 0.0), (7.4, 3.9, np.pi), (7.5, 0.6, np.pi)])
"""blue_0 on an open lane along y = 1.9 (B6 is at y 2.15..2.33, B4 starts at x 3.55)."""


def drive(
    contexts: dict, cmd: tuple = (2.0, 0.0, 0.0), decisions: int = 1, then_stop: int = 0
) -> np.ndarray:
    """blue_0's x after driving ``cmd`` from rest, optionally then commanding zero."""
    a = Arena(seed=1, action_space="continuous", mode="competitive")
    a.reset(contexts)
    a.place(START, bullets=[0, 0, 0, 0])
    xs = []
    for k in range(decisions + then_stop):
        c = cmd if k < decisions else (0.0, 0.0, 0.0)
        a.step([np.array([*c, 0]), *still(3)])
        xs.append(a.poses[0].copy())
    a.close()
    return np.array(xs)


def test_two_metres_per_second_settles_near_spec() -> None:
    x = drive({"Friction_coeff": 0.1}, decisions=2)
    # Second decision: settled; 0.4 s at ~1.97 m/s.
    assert (x[1, 0] - x[0, 0]) / 0.4 == pytest.approx(1.975, abs=0.01)
    x = drive({"Friction_coeff": 0.5}, decisions=2)
    assert (x[1, 0] - x[0, 0]) / 0.4 == pytest.approx(1.875, abs=0.015)


@pytest.mark.parametrize(
    ("key", "value", "slower"),
    [
        ("M", 10.0, True),
        ("Wheel_I", 0.05, True),
        ("VK1", 1.5, False),
        ("VK1", 0.1, True),
        ("KP", 2.0, True),
        ("vy_dt", 0.2, True),
        ("vx_dt", 0.2, False),
    ],
)
def test_dynamics_keys_move_the_step_response(key: str, value: float, slower: bool) -> None:
    base = drive({})[0, 0] - START[0, 0]
    moved = drive({key: value})[0, 0] - START[0, 0]
    if key == "vx_dt":  # a lateral delay leaves a forward command untouched
        assert moved == pytest.approx(base, abs=1e-9)
    elif slower:
        assert moved < base - 1e-3
    else:
        assert moved > base + 1e-3


def test_lower_friction_coasts_longer() -> None:
    def coast(mu: float) -> float:
        x = drive({"Friction_coeff": mu}, decisions=1, then_stop=1)
        return x[1, 0] - x[0, 0]

    assert coast(0.05) > coast(0.5) + 1e-3


def test_opponent_dynamics_apply_to_red_only() -> None:
    a = Arena(seed=1, action_space="continuous", mode="competitive")
    a.reset({"opponent.VK1": 0.05, "opponent_speed": 0.5})
    a.place(
        np.array([(1.0, 1.9, 0.0), (0.6, 3.9, 0.0), (1.0, 0.6, 0.0), (7.5, 3.9, np.pi)]),
        bullets=[0, 0, 0, 0],
    )
    fwd = np.array([2.0, 0.0, 0.0, 0])
    a.step([fwd, still(1)[0], fwd, still(1)[0]])
    assert a.poses[0, 0] - 1.0 > 2 * (a.poses[2, 0] - 1.0)
    a.close()


def test_robots_cannot_pass_walls_or_obstacles() -> None:
    a = Arena(seed=1, action_space="continuous", mode="competitive")
    a.reset()
    # blue_0 drives at the right wall, blue_1 at B5 from below, red_0 diagonally into a corner.
    a.place(
        np.array([(6.8, 1.9, 0.0), (4.04, 2.8, np.pi / 2), (1.0, 1.0, np.pi), (7.5, 3.9, 0)]),
        bullets=[0, 0, 0, 0],
    )
    push = np.array([2.0, 0.0, 0.0, 0])
    diag = np.array([1.5, -1.5, 0.0, 0])
    for _ in range(10):
        a.step([push, push, diag, still(1)[0]])
    assert a.poses[0, 0] <= F.FIELD_X - F.ROBOT_LENGTH / 2 + 0.01
    assert a.poses[1, 1] <= 3.445 - 0.0915 - F.ROBOT_LENGTH / 2 + 0.01
    assert a.poses[2, 0] >= F.ROBOT_WIDTH / 2 - 0.01 and a.poses[2, 1] >= F.ROBOT_WIDTH / 2 - 0.01
    a.close()


def test_episode_ends_on_time() -> None:
    a = Arena(seed=4, action_space="continuous", mode="competitive")
    a.reset()
    a.place(a.poses.copy(), bullets=[0, 0, 0, 0])
    steps, done, info = 0, False, {}
    while not done:
        _, _, done, info = a.step(still())
        steps += 1
    assert steps == 50 and info["t"] == F.EPISODE_STEPS and info["winner"] == "draw"
    with pytest.raises(ResetNeededError):
        a.step(still())
    a.close()


def test_step_before_reset_is_typed_error() -> None:
    a = Arena(seed=1)
    with pytest.raises(ResetNeededError):
        a.step([0, 0])
    a.close()


def _trajectory(seed: int) -> str:
    a = Arena(seed=seed)
    h = hashlib.sha256()
    for _ in range(2):
        obs = a.reset({"level": "middle"})
        rng = np.random.default_rng(0)
        done = False
        while not done:
            acts = [int(rng.choice(np.flatnonzero(m))) for m in a.get_avail_actions()]
            obs, rewards, done, _info = a.step(acts)
            for o in obs:
                h.update(o.tobytes())
            h.update(np.array(rewards).tobytes())
        h.update(a.get_state().tobytes())
    a.close()
    return h.hexdigest()


def test_determinism_within_and_across_processes() -> None:
    first = _trajectory(42)
    assert _trajectory(42) == first
    assert _trajectory(43) != first
    code = "from tests.server.test_arena import _trajectory; print(_trajectory(42))"
    out = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        check=True,
        cwd=str(__import__("pathlib").Path(__file__).parents[2]),
    )
    assert out.stdout.strip().splitlines()[-1] == first


def test_two_arenas_in_one_process_do_not_interfere() -> None:
    """Arena a plays as it does alone while b, another seed with other actions, steps in
    between each of its steps."""
    alone = Arena(seed=9)
    alone.reset()
    for _ in range(10):
        want, *_ = alone.step([1, 2])
    alone.close()
    a, b = Arena(seed=9), Arena(seed=4)
    a.reset()
    b.reset({"level": "hard"})
    for t in range(10):
        got, *_ = a.step([1, 2])
        _, _, done, _ = b.step([t % 8, 7 - t % 8])
        if done:
            b.reset()
    np.testing.assert_array_equal(np.stack(got), np.stack(want))
    assert a.world.client != b.world.client
    a.close()
    b.close()


def test_original_context_dicts_work() -> None:
    a = Arena(seed=1)
    a.reset({"coef": 0.5, "level": 1.0})
    assert a.context.coef == 0.5 and a.context.level == 1  # the released build's level 1
    a.reset({"VK1": 0.0375, "level": 0})
    assert a.context.blue_dynamics["vk1"] == 0.0375 and a.context.level == 0
    a.close()


@pytest.mark.parametrize(
    ("contexts", "needle"),
    [
        ({"VK2": 1.0}, "VK2"),
        ({"coef": -1.0}, "coef"),
        ({"level": 7}, "level"),
        ({"M": float("nan")}, "M"),
        ({"KP": "fast"}, "KP"),
        ({"level": [1]}, "level"),
        ({1: 0.5}, r"got \[1\]; valid keys: \[.*'coef'"),
    ],
)
def test_bad_contexts_name_the_key(contexts: dict, needle: str) -> None:
    a = Arena(seed=1)
    with pytest.raises(InvalidContextError, match=needle) as err:
        a.reset(contexts)
    assert isinstance(err.value, ValueError)
    a.close()


def test_bad_options_list_valid_ones() -> None:
    with pytest.raises(InvalidOptionError, match="valid options"):
        Arena(seed=1, warp_speed=True)
    with pytest.raises(InvalidOptionError, match="abstract"):
        Arena(seed=1, action_space="teleport")


@pytest.mark.parametrize(
    ("option", "said"),
    [
        ({"lidar": "false"}, "option lidar='false' must be True or False"),  # was: LiDAR on
        ({"zones": 1}, "option zones=1 must be True or False"),
        ({"candidate_obs": "no"}, "option candidate_obs='no' must be True, False or None"),
        ({"n_blue": 2.0}, "option n_blue=2.0 must be an integer in [1, 3]"),
    ],
)
def test_an_option_of_the_wrong_type_is_refused(option: dict[str, object], said: str) -> None:
    with pytest.raises(InvalidOptionError, match=re.escape(said)):
        ArenaConfig.from_options(option)


def test_numpy_numbers_and_switches_are_options_like_python_ones() -> None:
    """n_blue=np.int32(2) was refused ("must be an integer") while seed=np.int64 was taken."""
    cfg = ArenaConfig.from_options(
        {"n_blue": np.int32(3), "n_red": np.int64(3), "lidar_range": np.float32(5.0),
         "lidar": np.bool_(True), "candidate_obs": None}
    )  # fmt: skip
    assert (cfg.n_blue, cfg.n_red, cfg.lidar_range, cfg.lidar) == (3, 3, 5.0, True)
    assert all(type(v) in (int, float, bool, str, type(None)) for v in cfg.to_dict().values())


@pytest.mark.parametrize("seed", [-1, 2**63, 1.5, True, "7"])
def test_a_bad_seed_is_an_option_error_naming_the_range(seed: object) -> None:
    with pytest.raises(InvalidOptionError, match=r"seed .*\[0, 9223372036854775807\]"):
        Arena(seed=seed)  # type: ignore[arg-type]


def test_random_spawns_follow_released_rule() -> None:
    a = Arena(seed=3)
    for s in range(30):
        a.reset(seed=s)
        xy = a.poses[:, :2]
        assert ((xy[:, 0] >= 0.40) & (xy[:, 0] < 7.80)).all()
        assert ((xy[:, 1] >= 0.40) & (xy[:, 1] < 4.00)).all()
        d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
        assert d[np.triu_indices(4, 1)].min() >= 0.80
        assert np.allclose(np.round(xy * 100), xy * 100)
    a.close()


def test_corner_spawns() -> None:
    """Each robot inside its birth area, facing the other side; seeds start apart (placed
    exactly at the centres, every seed played the same episode against the bots)."""
    a = Arena(seed=3, spawn="corners")
    starts = []
    for seed in range(5):
        a.reset(seed=seed)
        off = a.poses[:, :2] - np.array(F.BIRTH_AREAS)
        assert np.abs(off).max() <= 0.15 + 1e-6
        np.testing.assert_allclose(np.cos(a.poses[:, 2]), [1, 1, -1, -1], atol=1e-3)
        starts.append(a.poses[:, :2].copy())
    assert len({s.round(3).tobytes() for s in starts}) == 5
    a.close()


def test_episode_in_long_lived_arena_equals_fresh_arena() -> None:
    """Robots are rebuilt at each reset: no contact or solver state leaks across episodes."""

    def play(arena: Arena, seed: int) -> bytes:
        obs = arena.reset({"level": "hard"}, seed=seed)
        out = [np.stack(obs).tobytes()]
        done = False
        while not done:
            obs, _, done, _ = arena.step([5, 2])
            out.append(np.stack(obs).tobytes())
        return b"".join(out)

    used = Arena(seed=0)
    play(used, 11)
    play(used, 12)
    fresh = Arena(seed=0)
    assert play(used, 13) == play(fresh, 13)
    used.close()
    fresh.close()


def _states(arena: Arena, contexts: dict, rows: list[list[int]]) -> list[list[float]]:
    arena.reset(contexts, seed=11)
    out = []
    for row in rows:
        arena.step(row)
        out.append(arena.get_state().tolist())
    return out


def test_competitive_bot_team_red_plays_as_the_cooperative_task() -> None:
    """With ``bot_team="red"`` red's bot drives red and its action rows are ignored, so a
    competitive arena plays exactly as a cooperative one given blue's same actions."""
    blue = [[1, 6], [3, 2], [7, 0], [4, 4]]
    coop, comp = Arena(seed=2), Arena(seed=2, mode="competitive")
    try:
        want = _states(coop, {"level": "hard"}, blue)
        ctx = {"level": "hard", "bot_team": "red"}
        assert _states(comp, ctx, [[*b, 0, 0] for b in blue]) == want
        assert _states(comp, ctx, [[*b, 5, 7] for b in blue]) == want
        assert comp.context.to_dict()["bot_team"] == "red"
        # without it the caller drives red: its actions move the red robots
        assert _states(comp, {"level": "hard"}, [[*b, 5, 7] for b in blue]) != want
    finally:
        coop.close()
        comp.close()


def test_competitive_bot_team_blue_ignores_blue_rows() -> None:
    arena = Arena(seed=2, mode="competitive", blue_level="middle")
    try:
        red = [[2, 5], [0, 3], [6, 6]]
        ctx = {"bot_team": "blue"}
        first = _states(arena, ctx, [[0, 0, *r] for r in red])
        assert _states(arena, ctx, [[7, 3, *r] for r in red]) == first
        assert _states(arena, {}, [[7, 3, *r] for r in red]) != first
    finally:
        arena.close()


@pytest.mark.parametrize("value", ["green", 1, None])
def test_bad_bot_team_lists_the_choices(value: object) -> None:
    arena = Arena(seed=1, mode="competitive")
    try:
        with pytest.raises(InvalidContextError, match=r"bot_team.*\['none', 'red', 'blue'\]"):
            arena.reset({"bot_team": value})
    finally:
        arena.close()
