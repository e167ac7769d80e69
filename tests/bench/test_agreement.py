"""bench/agreement.py: counting the games each number of policies wins."""

from __future__ import annotations

from bench.agreement import agreement


def test_agreement_counts_games_by_how_many_policies_win_them() -> None:
    won = [
        [True, True, False, False, True],
        [True, False, False, True, True],
        [True, True, False, False, False],
    ]
    summary = agreement(won)
    # game 0: 3 policies, 1: 2, 2: 0, 3: 1, 4: 2
    assert summary["games_won_by_k"] == [1, 1, 2, 1]
    assert summary["won_by_any"] == 0.8
    assert summary["won_by_all"] == 0.2
