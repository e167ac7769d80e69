"""``neuronsmae-league``: a round robin over policies and bots, rated with OpenSkill."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from PIL import Image

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.trainers.play.league import Player, expand, main
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
    from neuronsmae.trainers.play import league

    monkeypatch.setattr(league, "run_league", lambda *a, **k: pytest.fail("played"))
    taken = tmp_path / "taken"
    taken.write_text("a file")
    with pytest.raises(SystemExit) as exc:
        main(["--bots", "easy,hard", "--out", str(taken)])
    assert exc.value.code == 2
    assert f"--out {taken} exists and is not a directory" in capsys.readouterr().err


@pytest.mark.parametrize("kept", ["league.json", "league.md", "league.png"])
def test_an_out_holding_a_leagues_results_is_refused_before_any_game(
    kept: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """A second league into the same folder replaced the first one's results."""
    from neuronsmae.trainers.play import league

    monkeypatch.setattr(league, "play", lambda *a, **k: pytest.fail("played"))
    out = tmp_path / "lg"
    out.mkdir()
    (out / kept).write_text("an earlier league's")
    with pytest.raises(SystemExit) as exc:
        main(["--bots", "easy,hard", "--games", "2", "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"--out {out} already holds a league's results ({kept})" in err
    assert "choose another --out or remove them" in err
    assert (out / kept).read_text() == "an earlier league's"


@pytest.mark.parametrize("where", ["/proc/lg", "file/x"])
def test_an_out_that_cannot_be_written_is_refused_before_any_game(
    where: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """Both ended in a FileNotFoundError/NotADirectoryError traceback after every game."""
    from neuronsmae.trainers.play import league

    monkeypatch.setattr(league, "play", lambda *a, **k: pytest.fail("played"))
    (tmp_path / "file").write_text("a file")
    out = Path(where) if where.startswith("/") else tmp_path / where
    with pytest.raises(SystemExit) as exc:
        main(["--bots", "easy,hard", "--games", "2", "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"--out {out}: " in err
    assert ("cannot create the folder /proc/lg" if where.startswith("/") else
            f"{tmp_path / 'file'} is a file, not a folder") in err  # fmt: skip


def test_an_empty_new_out_is_checked_but_not_left_behind(tmp_path: Path) -> None:
    from neuronsmae.trainers.play.league import check_out

    check_out(tmp_path / "a" / "b")
    assert list(tmp_path.iterdir()) == []


def test_an_unreadable_snapshot_is_named_before_the_first_game(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A junk snapshot among good ones failed only when its first pair came up."""
    from neuronsmae.trainers.play import league

    snaps = tmp_path / "snaps" / "snapshots"
    snaps.mkdir(parents=True)
    make_checkpoint(snaps / "self_00000000.pt", 1)
    (snaps / "self_00000010.pt").write_bytes(b"not a checkpoint")
    make_checkpoint(snaps / "self_00000020.pt", 2)
    monkeypatch.setattr(league, "play", lambda *a, **k: pytest.fail("played"))
    out = tmp_path / "lg"
    assert main([str(tmp_path / "snaps"), "--bots", "", "--games", "40", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "self_00000010.pt is not a NeuronsMAE checkpoint" in err
    assert not out.exists()
