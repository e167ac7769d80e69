"""bench/outcomes.py: the summary separates close races at the time limit from the rest."""

from __future__ import annotations

import math

from bench.outcomes import summarize


def _game(
    winner: str,
    decisions: int,
    hp: tuple[float, float],
    bullets: tuple[int, int],
    per_bullet: tuple[float, float] = (1.0, 1.0),
    dry_at: tuple[int | None, int | None] = (None, None),
):
    return {
        "blue_damage_per_bullet": per_bullet[0],
        "red_damage_per_bullet": per_bullet[1],
        "blue_dry_at": dry_at[0],
        "red_dry_at": dry_at[1],
        "seed": 0,
        "winner": winner,
        "decisions": decisions,
        "blue_hp": hp[0],
        "red_hp": hp[1],
        "blue_bullets": bullets[0],
        "red_bullets": bullets[1],
        "kills": [0, 0, 0, 0],
    }


def test_summary_counts_limit_bullets_and_margins_per_outcome() -> None:
    games = [
        _game("blue", 20, (300.0, 0.0), (100, 50), (2.0, 1.0)),
        _game("blue", 50, (410.0, 400.0), (0, 0), (1.5, 1.25), (40, 30)),
        _game("red", 50, (380.0, 420.0), (0, 0), (1.0, 1.2), (35, 25)),
        _game("draw", 50, (460.0, 460.0), (0, 3), (1.1, float("nan")), (30, None)),
    ]
    won, lost = summarize(games, limit=50)
    assert won == {
        "outcome": "won",
        "episodes": 2,
        "at_time_limit": 1,
        "both_out_of_bullets": 1,
        "median_hp_margin": 155.0,
        "min_hp_margin": 10.0,
        "blue_damage_per_bullet": 1.75,
        "red_damage_per_bullet": 1.125,
        "blue_dry_at": 40,
        "red_dry_at": 30,
    }
    assert lost["episodes"] == 2 and lost["at_time_limit"] == 2
    assert lost["both_out_of_bullets"] == 1
    assert lost["median_hp_margin"] == 20.0 and lost["min_hp_margin"] == 0.0
    # missing values (no bullet fired, never ran dry) are left out of the medians
    assert lost["blue_damage_per_bullet"] == 1.05 and lost["red_damage_per_bullet"] == 1.2
    assert lost["blue_dry_at"] == 32.5 and lost["red_dry_at"] == 25


def test_summary_of_no_losses_has_no_margin() -> None:
    _, lost = summarize([_game("blue", 10, (100.0, 0.0), (5, 5))], limit=50)
    assert lost["episodes"] == 0 and math.isnan(lost["median_hp_margin"])
    assert math.isnan(lost["blue_dry_at"])
