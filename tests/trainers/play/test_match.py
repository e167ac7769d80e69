"""``neuronsmae-match``: bots, released levels and checkpoints on either side, in process
and over a server, with recordings that replay."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from neuronsmae.protocol.errors import InvalidContextError, InvalidOptionError
from neuronsmae.protocol.levels import LEVEL_ARGS
from neuronsmae.protocol.recording import read_recording
from neuronsmae.server.tools import replay as R
from neuronsmae.trainers.play import match as M
from tests.trainers.checkpoints import make_checkpoint


@pytest.fixture(scope="module")
def checkpoints(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    root = tmp_path_factory.mktemp("ckpt")
    return make_checkpoint(root / "a.pt", 1), make_checkpoint(root / "b.pt", 2)


def test_the_match_module_loads_neither_torch_nor_the_simulator() -> None:
    code = (
        "import sys, neuronsmae.trainers.play.match\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'ray', 'pybullet')"
        " or m.startswith('neuronsmae.server')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, timeout=120)  # fmt: skip
    assert out.stdout.strip() == "[]"


def test_bot_levels_on_both_sides_from_the_command_line(capsys: pytest.CaptureFixture) -> None:
    assert M.main(["--blue", "1", "--red", "0", "--episodes", "2", "--seed", "3", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["episodes"] == 2 and len(result["winners"]) == 2
    assert M.main(["--blue", "hard", "--red", "2", "--episodes", "1"]) == 2
    assert "'2' is neither a bot level (0, 1, easy" in capsys.readouterr().err


def test_play_refuses_zero_arenas_instead_of_playing_one() -> None:
    with pytest.raises(InvalidOptionError, match=r"arenas must be an integer \[1, 64\], got 0"):
        M.play("easy", "easy", 2, 0, arenas=0)


@pytest.mark.parametrize(
    ("kwargs", "error", "said"),
    [
        ({"episodes": 2.5}, InvalidOptionError, "episodes must be an integer >= 1, got 2.5"),
        ({"episodes": "2"}, InvalidOptionError, "episodes must be an integer >= 1, got '2'"),
        ({"episodes": 0}, InvalidOptionError, "episodes must be an integer >= 1, got 0"),
        ({"arenas": 100}, InvalidOptionError, r"arenas must be an integer \[1, 64\], got 100"),
        ({"arenas": 2.0}, InvalidOptionError, r"arenas must be an integer \[1, 64\], got 2.0"),
        ({"seed": 2**63 - 2, "episodes": 3}, InvalidContextError,
         r"seed=9223372036854775806 with episodes=3: .* must be in \[0, 9223372036854775805\]"),
        ({"seed": -1}, InvalidContextError, r"seed -1 is out of range; valid: \[0, "),
        ({"seed": 1.5}, InvalidContextError, "seed must be an integer"),
        ({"record": 5}, InvalidOptionError, r"record must be a path \(str or os.Path.*got int"),
        ({"gif": ["x.gif"]}, InvalidOptionError, r"gif must be a path \(str or os.Path.*got list"),
    ],
)  # fmt: skip
def test_play_names_the_argument_that_is_wrong_before_playing(
    kwargs: dict[str, Any], error: type[Exception], said: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """episodes=2.5 and arenas=100 named num_envs (the arena vector's), a seed whose last
    episode overflows named 'arena 0' once the first episodes were played."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    args: dict[str, Any] = {"episodes": 2, "seed": 0, **kwargs}
    with pytest.raises(error, match=said):
        M.play("easy", "easy", **args)


@pytest.mark.parametrize("side", [7, 2, None, 1.5, True, ["easy"]])
def test_a_side_neither_level_nor_path_lists_the_valid_sides(
    side: object, monkeypatch: pytest.MonkeyPatch
) -> None:
    """play(1, ...) gave pathlib's TypeError though evaluate_checkpoint takes level numbers."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    with pytest.raises(InvalidOptionError, match=r"--blue .* is neither a bot level \(0, 1, easy"):
        M.play(side, "easy", 1, 0)  # type: ignore[arg-type]


def test_level_numbers_and_paths_are_sides(
    checkpoints: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Levels as numbers (Python or NumPy), checkpoints as Path, and record/gif as str
    (record='/tmp/x' failed with AttributeError: 'str' object has no attribute 'exists')."""
    drawn: list[str] = []
    monkeypatch.setattr(
        "neuronsmae.server.tools.video.write_video", lambda path, frames: drawn.append(str(path))
    )
    rec, gif = str(tmp_path / "rec"), str(tmp_path / "first.gif")
    result = M.play(checkpoints[0], np.int64(1), np.int64(1), np.int64(4), record=rec, gif=gif)
    assert (result["blue"], result["red"], result["seed"]) == (str(checkpoints[0]), "1", 4)
    assert [f.name for f in Path(rec).iterdir()] == ["episode_00000_s4.jsonl.gz"]
    assert drawn == [gif]
    bots = M.play(0, "easy", 1, 4)
    assert bots["blue"] == "0" and len(bots["winners"]) == 1


def test_options_the_match_sets_itself_and_zero_servers_are_refused(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """--option mode=bots was silently overridden, and --servers 0 played on one server."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    for option in ("mode=competitive", "blue_level=easy"):
        assert M.main(["--episodes", "1", "--option", option]) == 2
        assert f"options ['{option.split('=')[0]}'] are the match's own" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        M.main(["--episodes", "1", "--servers", "0"])
    assert "--servers must be at least 1, got 0" in capsys.readouterr().err


def test_a_record_dir_that_is_a_file_is_refused_before_playing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It used to fail with a bare FileExistsError once the first episode had been played."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    taken = tmp_path / "taken"
    taken.write_text("a file")
    with pytest.raises(InvalidOptionError, match=f"record: {taken} exists and is not a dir"):
        M.play("easy", "easy", 2, 0, record=taken)


def test_a_record_dir_holding_recordings_is_refused_before_playing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A second match into the same folder overwrote the first one's episode files."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    (tmp_path / "episode_00000_s0.jsonl.gz").write_bytes(b"an earlier match's")
    (tmp_path / "notes.txt").write_text("other files do not count")
    with pytest.raises(InvalidOptionError, match="already holds 1 recording"):
        M.play("easy", "easy", 2, 0, record=tmp_path)


@pytest.mark.parametrize("where", ["/proc/x.gif", "folder.gif", "file/x.gif"])
def test_a_gif_that_cannot_be_written_is_refused_before_playing(
    where: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    """Each failed only once every episode had been played, and no score was printed."""
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    (tmp_path / "folder.gif").mkdir()
    (tmp_path / "file").write_text("a file")
    gif = Path(where) if where.startswith("/") else tmp_path / where
    assert M.main(["--episodes", "400", "--gif", str(gif)]) == 2
    err = capsys.readouterr().err
    said = {
        "/proc/x.gif": "--gif /proc/x.gif: cannot write into /proc",
        "folder.gif": f"--gif {gif} is a folder; name a file to write",
        "file/x.gif": f"--gif {gif}: {tmp_path / 'file'} is a file, not a folder",
    }[where]
    assert said in err
    assert "replaced if it exists" in " ".join(M.build_parser().format_help().split())


def test_a_record_dir_that_cannot_be_created_is_refused_before_playing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(M, "open_arenas", lambda *a, **k: pytest.fail("played"))
    (tmp_path / "file").write_text("a file")
    with pytest.raises(InvalidOptionError, match=r"--record .*file is a file, not a folder"):
        M.play("easy", "easy", 2, 0, record=tmp_path / "file" / "rec")


def test_a_side_no_loader_takes_names_the_levels_and_the_loaders() -> None:
    with pytest.raises(InvalidOptionError, match=r"--red 'nowhere.pt'.*loaders: .*qlearner"):
        M.play("easy", "nowhere.pt", 1, 0)


def test_a_checkpoint_of_another_layout_is_refused(checkpoints: tuple[Path, Path],
                                                   tmp_path: Path) -> None:  # fmt: skip
    three = make_checkpoint(tmp_path / "3v3.pt", 3, n_blue=3, n_red=3)
    with pytest.raises(InvalidOptionError, match=r"--red .*another layout.*team_size: 2 ≠ 3"):
        M.play(str(three), str(checkpoints[0]), 1, 0)


@pytest.mark.slow
def test_two_checkpoints_in_process_record_replayable_episodes(
    checkpoints: tuple[Path, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    a, b = (str(p) for p in checkpoints)
    drawn: list[int] = []
    monkeypatch.setattr(
        "neuronsmae.server.tools.video.write_video", lambda path, frames: drawn.append(len(frames))
    )
    out = tmp_path / "rec"
    result = M.play(a, b, 3, 5, arenas=2, record=out, gif=tmp_path / "first.gif")
    files = sorted(out.glob("*.jsonl.gz"))
    assert [f.name for f in files] == [f"episode_{i:05d}_s{5 + i}.jsonl.gz" for i in range(3)]
    recs = [read_recording(f) for f in files]
    assert all(r.complete and r.options["mode"] == "competitive" for r in recs)
    assert [r.winner for r in recs] == result["winners"]
    for rec in recs:  # the in-process simulator re-plays every decision identically
        assert R.replay(rec).decisions == len(rec.decisions)
    assert drawn == [len(recs[0].decisions) + 1]
    swapped = M.play(b, a, 3, 5, arenas=3)
    assert swapped["blue"] == b and len(swapped["winners"]) == 3


@pytest.mark.slow
def test_a_checkpoint_against_every_bot_and_released_level_on_either_side(
    checkpoints: tuple[Path, Path],
) -> None:
    a = str(checkpoints[0])
    for level in LEVEL_ARGS:
        as_blue = M.play(a, level, 1, 7, arenas=1)
        as_red = M.play(level, a, 1, 7, arenas=1)
        for result, (blue, red) in ((as_blue, (a, level)), (as_red, (level, a))):
            assert (result["blue"], result["red"]) == (blue, red)
            (winner,) = result["winners"]
            assert winner in ("blue", "red", "draw")
            assert result[f"{winner}_rate" if winner == "draw" else f"{winner}_win_rate"] == 1.0
            rates = result["blue_win_rate"] + result["red_win_rate"] + result["draw_rate"]
            assert rates == 1.0
    again = M.play(a, "hard", 3, 7, arenas=1)
    assert again["winners"] == M.play(a, "hard", 3, 7, arenas=3)["winners"]  # same starts


@pytest.mark.slow
def test_over_a_server_the_match_plays_as_in_process(checkpoints: tuple[Path, Path]) -> None:
    a, b = (str(p) for p in checkpoints)
    here = M.play(a, b, 3, 11, arenas=3)
    served = M.play(a, b, 3, 11, arenas=3, servers=1)
    assert served["winners"] == here["winners"]
    bot_here = M.play("hard", a, 2, 11, arenas=2)
    assert M.play("hard", a, 2, 11, arenas=2, servers=2)["winners"] == bot_here["winners"]


def test_the_wilson_interval_holds_the_rate_and_is_exact_at_the_ends() -> None:
    assert M.wilson(0, 200)[0] == 0.0 and M.wilson(200, 200)[1] == 1.0
    for k in (0, 1, 37, 100, 199, 200):
        low, high = M.wilson(k, 200)
        assert 0.0 <= low <= k / 200 <= high <= 1.0
    low, high = M.wilson(100, 200)  # p = 0.5, n = 200: 0.5 ± 1.96·√(0.25/200) nearly
    assert (low, high) == pytest.approx((0.4314, 0.5686), abs=1e-3)
    assert M.wilson(0, 0) == (0.0, 1.0)
