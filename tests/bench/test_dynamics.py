"""bench/bench_dynamics.py: the measured response moves the way each knob says it should."""

from __future__ import annotations

import pytest

from bench.bench_dynamics import make_arena, measure


@pytest.fixture(scope="module")
def arena():
    a = make_arena()
    yield a
    a.close()


def test_more_friction_settles_slower_and_stops_shorter(arena) -> None:
    low, high = measure("Friction_coeff", 0.1, arena), measure("Friction_coeff", 1.0, arena)
    assert low["fwd_settled"] == pytest.approx(1.975, abs=0.005)  # the spec's calibration
    assert high["fwd_settled"] < low["fwd_settled"] - 0.2
    assert high["fwd_stop"] < low["fwd_stop"]
    assert high["turn_settled"] < low["turn_settled"]
    assert high["fwd_t63"] == pytest.approx(low["fwd_t63"], abs=0.005)  # not the time constant


def test_a_forward_delay_delays_only_the_forward_axis(arena) -> None:
    none, late = measure("vy_dt", 0.0, arena), measure("vy_dt", 0.2, arena)
    assert late["fwd_lag"] - none["fwd_lag"] == pytest.approx(0.2, abs=0.02)
    assert late["fwd_stop"] > none["fwd_stop"] + 0.3  # 0.2 s more at ~2 m/s
    assert late["lat_lag"] == none["lat_lag"] and late["turn_lag"] == none["turn_lag"]
