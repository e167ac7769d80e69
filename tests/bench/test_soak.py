"""bench/soak.py: windows of latency and CPU per decision, and a short vector soak."""

from __future__ import annotations

import itertools

import pytest

from bench.soak import soak, windows


def test_windows_split_latency_and_cpu_at_the_marks() -> None:
    # One request every 2 decisions; 1 ms before decision 3000, 2 ms from there on.
    latency = [(k, 0.001 if k < 3000 else 0.002) for k in range(0, 6000, 2)]
    marks = [(1000, 0.0), (3000, 2.0), (5000, 6.0), (6000, 7.0)]
    rows = windows({"latency": latency, "cpu_marks": marks}, warmup=1000, window=2000)
    assert [r["decisions"] for r in rows] == ["1000-2999", "3000-4999", "5000-5999"]
    assert [r["n"] for r in rows] == [2000, 2000, 1000]
    assert [r["p50_ms"] for r in rows] == pytest.approx([1.0, 2.0, 2.0])
    assert [r["cpu_us_per_decision"] for r in rows] == pytest.approx([1000.0, 2000.0, 1000.0])


@pytest.mark.slow
def test_a_short_vector_soak_counts_every_arena_and_marks_every_window() -> None:
    run = soak(decisions=1200, warmup=200, action_space="discrete", envs=4, window=400)
    assert run["decisions"] == 1200  # 300 requests of 4 decisions
    assert len(run["latency"]) == 300
    assert [k for k, _ in run["cpu_marks"]] == [200, 600, 1000, 1200]
    cpu = [c for _, c in run["cpu_marks"]]
    assert all(b > a for a, b in itertools.pairwise(cpu))  # both processes worked
    assert run["episodes"] >= 4 + 4 * 5  # 4, then one per arena every ≤ 51 requests (50 + reset)
    assert run["end"]["server"]["fds"] == run["base"]["server"]["fds"]
    rows = windows(run, 200, 400)
    assert [r["n"] for r in rows] == [400, 400, 200]
