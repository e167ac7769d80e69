"""bench/zenoh_floor.py and the bound bench_transport derives from it."""

from __future__ import annotations

import pytest

from bench.bench_transport import bound
from bench.zenoh_floor import held_floor, measure


@pytest.mark.slow
def test_both_floors_are_measured_against_real_echo_servers() -> None:
    rows = measure(pings=30)
    assert [row["path"] for row in rows] == [
        "zenoh query",
        "zenoh query, server polling",
        "zenoh publish/subscribe",
        "tcp socket",
    ]
    for row in rows:
        assert row["pings"] == 30
        assert 0 < row["median_us"] <= row["p99_us"] < 2e6


@pytest.mark.parametrize(
    ("per_s", "floor_us", "expected"),
    [(1000.0, 0.0, 1.0), (1000.0, 1000.0, 0.5), (2000.0, 500.0, 0.5), (1600.0, 187.0, 0.77)],
)
def test_bound_is_a_decision_against_itself_plus_the_floor(
    per_s: float, floor_us: float, expected: float
) -> None:
    assert bound(per_s, floor_us) == pytest.approx(expected, abs=1e-3)


@pytest.mark.slow
def test_the_vector_floor_is_a_held_query_less_its_hold() -> None:
    row = held_floor(pings=10, arenas=2)
    parts = ("client_main_us", "client_other_us", "server_main_us", "server_other_us")
    assert row["floor_us_per_query"] == pytest.approx(sum(row[p] for p in parts), abs=0.5)
    assert row["hold_ms"] == pytest.approx(2 * row["in_process_decision_us"] / 1e3, abs=0.01)
    # The held server spins through each hold: its main thread's CPU, less the holds, is the
    # query's handling only, far below one hold.
    assert 0 < row["server_main_us"] < row["hold_ms"] * 1e3
    assert row["client_main_us"] > 0 and row["client_other_us"] > 0
    per_decision = row["floor_us_per_query"] / 2
    assert row["floor_us_per_decision"] == pytest.approx(per_decision, abs=0.1)
    decision = row["in_process_decision_us"]
    assert row["cpu_ratio_bound"] == pytest.approx(decision / (decision + per_decision), abs=1e-3)


@pytest.mark.slow
def test_the_arena_held_floor_subtracts_the_arenas_reported_cpu() -> None:
    row = held_floor(pings=10, arenas=2, hold="arenas")
    assert row["hold"] == "arenas"
    # The server reports what its arenas took: about two in-process decisions per query.
    decisions_ms = 2 * row["in_process_decision_us"] / 1e3
    assert 0.3 * decisions_ms < row["hold_ms"] < 3 * decisions_ms
    parts = ("client_main_us", "client_other_us", "server_main_us", "server_other_us")
    assert row["floor_us_per_query"] == pytest.approx(sum(row[p] for p in parts), abs=0.5)
    assert row["server_main_us"] < row["hold_ms"] * 1e3


def test_an_unknown_hold_is_refused_with_the_valid_ones() -> None:
    with pytest.raises(ValueError, match="spin"):
        held_floor(pings=1, arenas=1, hold="sleep")
