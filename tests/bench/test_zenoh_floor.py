"""bench/zenoh_floor.py and the bound bench_transport derives from it."""

from __future__ import annotations

import pytest

from bench.bench_transport import bound
from bench.zenoh_floor import measure


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
