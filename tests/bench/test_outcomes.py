"""bench/outcomes.py: the summary separates close races at the time limit from the rest."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from bench import outcomes
from bench.outcomes import by_opening_value, summarize
from neuronsmae.protocol.messages import MAX_SEED


def _game(
    winner: str,
    decisions: int,
    hp: tuple[float, float],
    bullets: tuple[int, int],
    per_bullet: tuple[float, float] = (1.0, 1.0),
    dry_at: tuple[int | None, int | None] = (None, None),
    opening_value: float = 0.0,
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
        "opening_value": opening_value,
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


def test_win_rate_by_fifth_of_the_agents_own_opening_value() -> None:
    # Ten games; the agents valued the start v = 0..9 and won every game valued 4 or more,
    # and the one valued 1.
    games = [
        _game("blue" if v >= 4 or v == 1 else "red", 50, (1.0, 0.0), (0, 0), opening_value=v)
        for v in (7.0, 2.0, 9.0, 0.0, 5.0, 1.0, 8.0, 3.0, 6.0, 4.0)
    ]
    rows = by_opening_value(games)
    assert [(r["lowest_value"], r["highest_value"]) for r in rows] == [
        (0.0, 1.0), (2.0, 3.0), (4.0, 5.0), (6.0, 7.0), (8.0, 9.0)
    ]  # fmt: skip
    assert [r["win_rate"] for r in rows] == [0.5, 0.0, 1.0, 1.0, 1.0]
    assert [r["episodes"] for r in rows] == [2] * 5
    assert len(by_opening_value(games[:3])) == 3  # fewer games than fifths: no empty rows


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from tests.trainers.checkpoints import make_checkpoint

    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "a.pt", 1)


def test_bad_checkpoints_seeds_and_outputs_are_usage_errors(
    checkpoint: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """A corrupt or missing checkpoint and a seed past the largest were tracebacks."""
    monkeypatch.setattr(outcomes, "play", lambda *a, **k: pytest.fail("played"))
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    kept = tmp_path / "keep.json"
    kept.write_text("{}")
    (tmp_path / "file").write_text("a file")
    cases = [
        ([str(junk)], "junk.pt is not a NeuronsMAE checkpoint"),
        ([str(tmp_path / "nowhere.pt")], "nowhere.pt"),
        ([str(checkpoint), "--seed", "99999999999999999999"], "must be in [0, "),
        ([str(checkpoint), "--seed", str(MAX_SEED), "--episodes", "2"], "past the largest seed"),
        ([str(checkpoint), "--out", str(kept)], "pass --force to replace it"),
        ([str(checkpoint), "--out", str(tmp_path / "file" / "o.json")], "is a file, not a folder"),
        ([str(checkpoint), "--out", str(tmp_path / "o.txt")], "--out must name a .json file"),
    ]
    for argv, said in cases:
        with pytest.raises(SystemExit) as exc:
            outcomes.main(argv)
        assert exc.value.code == 2
        assert said in capsys.readouterr().err
    assert kept.read_text() == "{}"


def test_a_checkpoint_of_another_layout_is_refused_before_playing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from tests.trainers.checkpoints import make_checkpoint

    monkeypatch.setattr(outcomes, "play", lambda *a, **k: pytest.fail("played"))
    three = make_checkpoint(tmp_path / "3v3.pt", 3, n_blue=3, n_red=3)
    with pytest.raises(SystemExit):
        outcomes.main([str(three)])
    assert "was trained on another layout" in capsys.readouterr().err


def test_out_receives_the_report_and_bench_out_is_left_alone(
    checkpoint: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    game = _game("red", 50, (1.0, 2.0), (0, 0))
    monkeypatch.setattr(outcomes, "play", lambda *a, **k: dict(game))
    monkeypatch.setattr(outcomes, "write_json", lambda *a: pytest.fail("wrote bench/out"))
    out = tmp_path / "o.json"
    assert outcomes.main([str(checkpoint), "--episodes", "3", "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert report["checkpoint"] == str(checkpoint) and len(report["games"]) == 3
    assert outcomes.main([str(checkpoint), "--episodes", "1", "--out", str(out), "--force"]) == 0
    assert len(json.loads(out.read_text())["games"]) == 1
