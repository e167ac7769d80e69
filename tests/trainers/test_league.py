"""``neuronsmae-league``: a round robin over policies and bots, rated with OpenSkill."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.trainers.league import Player, expand, main
from tests.trainers.checkpoints import make_checkpoint

pytestmark = pytest.mark.slow  # plays a few dozen episodes


def test_a_run_directory_expands_to_its_snapshots_then_its_checkpoint(tmp_path: Path) -> None:
    run = tmp_path / "run"
    for name in ("snapshots/self_00000000.pt", "snapshots/self_00000500.pt", "checkpoint.pt"):
        (run / name).parent.mkdir(parents=True, exist_ok=True)
        (run / name).write_bytes(b"")
    players = expand([str(run)], ["easy"])
    assert [p.name for p in players] == [
        "run/self_00000000", "run/self_00000500", "run/checkpoint", "bot:easy",
    ]  # fmt: skip
    assert players[-1] == Player("easy", "bot:easy")
    with pytest.raises(InvalidOptionError, match="at least two players"):
        expand([], ["easy"])
    with pytest.raises(InvalidOptionError, match="'expert' is not a bot level"):
        expand([], ["easy", "expert"])


def test_a_league_of_three_policies_rates_them_and_draws_the_matrix(tmp_path: Path) -> None:
    run = tmp_path / "run" / "snapshots"
    run.mkdir(parents=True)
    make_checkpoint(run / "self_00000000.pt", 1)
    make_checkpoint(run / "self_00000010.pt", 2)
    out = tmp_path / "league"
    argv = [str(tmp_path / "run"), "--bots", "hard", "--games", "4", "--arenas", "2"]
    assert main([*argv, "--out", str(out)]) == 0
    league = json.loads((out / "league.json").read_text())
    names = ["run/self_00000000", "run/self_00000010", "bot:hard"]
    assert league["players"] == names
    assert sorted(r["player"] for r in league["ratings"]) == sorted(names)
    mus = [r["mu"] for r in league["ratings"]]
    assert mus == sorted(mus, reverse=True)
    for row in league["ratings"]:
        assert row["lo"] < row["mu"] < row["hi"] and row["sigma"] < 25 / 3  # moved from the prior
    m = league["matrix"]
    for i in range(3):
        assert m[i][i] is None
        for j in range(3):
            if i != j:
                assert m[i][j] + m[j][i] == pytest.approx(1.0)
    # the player that scored most over its games is rated above the one that scored least
    totals = {names[i]: sum(v for v in m[i] if v is not None) for i in range(3)}
    order = [r["player"] for r in league["ratings"]]
    best, worst = max(totals, key=totals.get), min(totals, key=totals.get)
    assert totals[best] > totals[worst] and order.index(best) < order.index(worst)
    assert len(league["pairs"]) == 6  # three pairs, each colour once
    assert sum(p["episodes"] for p in league["pairs"]) == 3 * 4
    assert "| 1 |" in (out / "league.md").read_text()
    with Image.open(out / "league.png") as picture:
        assert picture.size[0] > 200 and picture.size[1] > 200


@pytest.mark.parametrize("argv", [["--arenas", "0"], ["--servers", "0"]])
def test_zero_arenas_or_servers_is_a_usage_error(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    assert "--arenas and --servers must be at least 1" in capsys.readouterr().err


def test_a_player_named_twice_is_refused(tmp_path: Path) -> None:
    """A bot or checkpoint given twice used to enter the league as two players."""
    run = tmp_path / "run"
    (run / "checkpoint.pt").parent.mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(InvalidOptionError, match=r"named twice: \['easy'\]"):
        expand([], ["easy", "hard", "easy"])
    with pytest.raises(InvalidOptionError, match="named twice"):
        expand([str(run), str(run / "checkpoint.pt")], ["easy"])


def test_an_out_that_is_a_file_is_refused_before_the_league_is_played(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """It used to end in FileExistsError after every game had been played."""
    from neuronsmae.trainers import league

    monkeypatch.setattr(league, "run_league", lambda *a, **k: pytest.fail("played"))
    taken = tmp_path / "taken"
    taken.write_text("a file")
    with pytest.raises(SystemExit) as exc:
        main(["--bots", "easy,hard", "--out", str(taken)])
    assert exc.value.code == 2
    assert f"--out {taken} exists and is not a directory" in capsys.readouterr().err
