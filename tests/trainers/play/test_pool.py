"""The opponent pool: members, the δ-uniform draw, the snapshot schedule, its state."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest

from neuronsmae.trainers.play.pool import (
    Member,
    OpponentPool,
    SelfPlayConfig,
    parse_opponents,
    window_start,
)
from neuronsmae.trainers.run.config import ConfigError, make_config


def test_entries_are_bots_checkpoints_and_self(tmp_path: Path) -> None:
    ckpt = tmp_path / "a.pt"
    ckpt.write_bytes(b"")
    fixed, self_play = parse_opponents(f"easy, 1,{ckpt},self")
    assert [m.id for m in fixed] == ["bot:easy", "bot:1", f"ckpt:{ckpt}"]
    assert self_play and [m.is_policy for m in fixed] == [False, False, True]
    assert fixed[1].contexts() == {"level": 1, "bot_team": "red"}
    assert Member("self:40").contexts() == {"bot_team": "none"}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("expert", r"opponent entry 'expert' is neither a bot level \(0, 1, easy"),
        ("easy,easy", "names a member twice"),
        ("self,self", r"names a member twice \('self'\)"),  # was taken
        (",", "empty entry"),  # an empty pool, as if no --opponent were given
        ("easy,,hard", "empty entry"),
        ("runs/none.pt", "existing checkpoint"),
    ],
)
def test_bad_entries_name_what_is_valid(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_opponents(text)


def test_a_policy_on_red_needs_equal_teams() -> None:
    with pytest.raises(ConfigError, match=r"equal teams.*n_blue=3.*n_red=2"):
        make_config({"opponent": "self", "n_blue": 3, "n_red": 2})
    make_config({"opponent": "easy,hard", "n_blue": 3, "n_red": 2})  # bots only: fine


@pytest.mark.parametrize(
    ("n", "delta", "start"), [(1, 0.5, 0), (5, 0.5, 2), (5, 0.0, 0), (5, 1.0, 4), (10, 0.5, 4)]
)
def test_the_window_is_the_newest_part_of_the_history(n: int, delta: float, start: int) -> None:
    assert window_start(n, delta) == start


def _pool(text: str, snapshots: int, delta: float = 0.5, seed: int = 3) -> OpponentPool:
    pool = OpponentPool(text, SelfPlayConfig(snapshot_every=10, delta=delta), seed)
    for e in range(snapshots):
        pool.add_snapshot(10 * e, object())
    return pool


def test_draws_are_uniform_over_the_fixed_members_and_the_window() -> None:
    pool = _pool("easy,hard,self", snapshots=5)  # window: snapshots 2, 3, 4
    assert [m.id for m in pool.candidates()] == [
        "bot:easy", "bot:hard", "self:20", "self:30", "self:40",
    ]  # fmt: skip
    counts = Counter(pool.draw(k).id for k in range(5000))
    assert set(counts) == {m.id for m in pool.candidates()}
    assert all(abs(c / 5000 - 0.2) < 0.025 for c in counts.values()), counts  # 5σ ≈ 0.028


def test_delta_one_plays_the_latest_and_zero_the_whole_history() -> None:
    assert {_pool("self", 6, delta=1.0).draw(k).id for k in range(200)} == {"self:50"}
    history = {_pool("self", 6, delta=0.0).draw(k).id for k in range(200)}
    assert history == {f"self:{10 * e}" for e in range(6)}


def test_a_draw_depends_only_on_the_seed_the_episode_and_the_pool() -> None:
    a, b = _pool("easy,self", 4), _pool("easy,self", 4)
    assert [a.draw(k).id for k in range(50)] == [b.draw(k).id for k in range(50)]
    other = _pool("easy,self", 4, seed=4)
    assert [a.draw(k).id for k in range(50)] != [other.draw(k).id for k in range(50)]


def test_snapshots_fall_due_at_the_start_then_every_n_episodes() -> None:
    pool = _pool("self", 0)
    assert pool.snapshot_due(0, 0)  # the first: the weights the run starts with
    pool.add_snapshot(0, object())
    assert not pool.snapshot_due(0, 9) and pool.snapshot_due(8, 12) and pool.snapshot_due(9, 10)
    assert not _pool("easy", 0).snapshot_due(0, 100)  # no self-play, no snapshots


def test_state_round_trip_needs_every_policy() -> None:
    pool = _pool("easy,self", 3)
    state = pool.state_dict()
    assert state == {"snapshots": [0, 10, 20]}
    fresh = _pool("easy,self", 0)
    with pytest.raises(ConfigError, match="self:20"):
        fresh.load_state_dict(state, {"self:0": 1, "self:10": 2})
    fresh.load_state_dict(state, {"self:0": 1, "self:10": 2, "self:20": 3})
    assert [m.id for m in fresh.candidates()] == [m.id for m in pool.candidates()]
    assert fresh.policies() == {"self:10": 2, "self:20": 3}
