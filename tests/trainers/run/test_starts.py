"""The replay of lost training starts: which seeds come back, how often, and resume."""

from __future__ import annotations

import numpy as np
import pytest

from neuronsmae.trainers.run.config import ConfigError, make_config
from neuronsmae.trainers.run.experimental import StartReplay


def _fresh(k: int) -> int:
    return 1000 + k


def test_off_never_replays_tracks_nothing_and_draws_nothing() -> None:
    starts = StartReplay(0.0, 3, 8, seed=1)
    before = starts.rng.bit_generator.state
    for k in range(20):
        assert starts.choose(_fresh(k)) == _fresh(k)
        starts.record(_fresh(k), won=False)
    assert not starts.queued and starts.replays == 0
    assert starts.rng.bit_generator.state == before  # a run without replay keeps its streams


def test_only_starts_not_won_come_back_and_each_at_most_max_plays_times() -> None:
    starts = StartReplay(1.0, 3, 64, seed=1)
    starts.record(5, won=True)
    starts.record(6, won=False)
    starts.record(7, won=False)
    issued = [starts.choose(_fresh(k)) for k in range(3)]
    # p = 1: both queued starts are replayed, then the queue is empty and fresh seeds follow
    assert sorted(issued[:2]) == [6, 7] and issued[2] == _fresh(2)
    starts.record(6, won=True)  # won on replay: gone for good
    starts.record(7, won=False)  # lost twice: queued for its third and last play
    assert list(starts.queued.items()) == [(7, 2)]
    assert starts.choose(_fresh(3)) == 7
    starts.record(7, won=False)  # third play lost: dropped, some starts are unwinnable
    assert not starts.queued and starts.replays == 3
    assert starts.choose(_fresh(4)) == _fresh(4)


def test_a_start_in_flight_is_never_issued_twice() -> None:
    starts = StartReplay(1.0, 5, 64, seed=2)
    starts.record(9, won=False)
    assert starts.choose(_fresh(0)) == 9
    assert [starts.choose(_fresh(k)) for k in range(1, 4)] == [_fresh(1), _fresh(2), _fresh(3)]


def test_capacity_keeps_the_most_recent_losses() -> None:
    starts = StartReplay(0.5, 3, 3, seed=3)
    for seed in range(10):
        starts.record(seed, won=False)
    assert list(starts.queued) == [7, 8, 9]


def test_replay_probability_is_p_while_losses_are_queued() -> None:
    starts = StartReplay(0.3, 2, 10_000, seed=4)
    for seed in range(5000):
        starts.record(-1 - seed, won=False)
    n = 2000
    replays = sum(starts.choose(_fresh(k)) < 0 for k in range(n))
    assert replays == starts.replays
    assert abs(replays / n - 0.3) < 4 * np.sqrt(0.3 * 0.7 / n)


def test_state_round_trip_continues_identically_and_requeues_in_flight() -> None:
    a = StartReplay(0.5, 3, 16, seed=5)
    for seed in range(10):
        a.record(seed, won=seed % 3 == 0)
    in_flight = next(s for s in (a.choose(_fresh(k)) for k in range(50)) if s < 1000)
    state = a.state_dict()
    b = StartReplay(0.5, 3, 16, seed=99)
    b.load_state_dict(state)
    assert in_flight in b.queued and not b.out and b.replays == a.replays
    a.queued[in_flight] = a.out.pop(in_flight)  # what a resumed run sees
    assert [a.choose(_fresh(k)) for k in range(20)] == [b.choose(_fresh(k)) for k in range(20)]


@pytest.mark.parametrize(
    ("key", "value", "words"),
    [
        ("start_replay", "1.5", "start_replay must lie in [0, 1]"),
        ("start_replay", "-0.1", "start_replay must lie in [0, 1]"),
        ("start_replay_plays", "1", "start_replay_plays must be ≥ 2"),
        ("start_replay_capacity", "0", "start_replay_capacity ≥ 1"),
    ],
)
def test_config_rejects_out_of_range_values(key: str, value: str, words: str) -> None:
    with pytest.raises(ConfigError, match=words.replace("[", r"\[").replace("]", r"\]")):
        make_config({}, {key: value})


def test_bad_arguments_are_a_value_error_not_an_assert() -> None:
    with pytest.raises(ValueError, match="max_plays ≥ 2"):  # an AssertionError, gone under -O
        StartReplay(0.5, 1, 8, seed=1)
