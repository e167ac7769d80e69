"""bench/request_cost.py: every piece of a vector request timed in three cache states."""

from __future__ import annotations

import numpy as np
import pytest

from bench.request_cost import STATES, cpu_us, run


def test_cpu_us_runs_the_preparation_untimed() -> None:
    calls: list[str] = []
    slow = np.ones(8 << 20)  # 64 MiB: several ms to sum
    cost = cpu_us(lambda: calls.append("timed"), lambda: (calls.append("before"), slow.sum()), 5)
    assert calls == ["before", "timed"] * 5
    assert 0 <= cost < 1000  # appending is timed; summing 64 MiB before it is not


@pytest.mark.slow
def test_every_piece_is_timed_in_every_state_and_the_wholes_add_up() -> None:
    rows, decisions_us = run(k=2, samples=5)
    assert [row["piece"] for row in rows] == [
        "client: encode request",
        "server: decode request",
        "server: handle, arenas aside",
        "server: encode reply",
        "client: decode reply",
        "client: VecRM.step, transport aside",
        "both wholes: handle + VecRM.step",
    ]
    for state in STATES:
        key = f"{state}_us"
        assert all(row[key] > 0 for row in rows)
        assert rows[-1][key] == pytest.approx(rows[2][key] + rows[5][key], abs=0.11)
    assert decisions_us > 0
