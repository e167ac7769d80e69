"""bench.summarize_runs: a finished run directory's figures, as docs/data keeps them."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from bench.summarize_runs import main, summarize
from neuronsmae.trainers.run.records import EVAL_COLUMNS, TRAIN_COLUMNS


def _write(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, restval="0")
        writer.writeheader()
        writer.writerows(rows)


def _run(tmp_path: Path, finished: bool = True) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"alg": "vdn", "level": "easy", "seed": 3,
                                                 "arena": {"n_blue": 3}, "lr": 1e-3}))  # fmt: skip
    evals = [{"episodes": 500, "env_steps": 2e4, "win_rate": 0.5, "eval_episodes": 50,
              "split": "validation", "weights": "latest", "contexts": "main"}]  # fmt: skip
    if finished:
        for weights, rate in (("latest", 0.8), ("best", 0.75)):
            evals.append({"episodes": 900, "env_steps": 40000, "win_rate": rate, "draw_rate": 0.0,
                          "loss_rate": 1 - rate, "mean_return": 3.0, "eval_episodes": 200,
                          "split": "test", "weights": weights, "contexts": "main"})  # fmt: skip
        evals.append({**evals[-1], "weights": "latest", "contexts": "coef=1.5", "win_rate": 0.6})
    _write(run / "eval.csv", EVAL_COLUMNS, evals)
    _write(run / "train.csv", TRAIN_COLUMNS, [{"updates": 1700, "wall_seconds": 1800.5}])
    return run


def test_summary_keeps_settings_counters_tests_and_curve(tmp_path: Path) -> None:
    s = summarize("var", _run(tmp_path))
    assert (s["episodes"], s["env_steps"], s["updates"]) == (900, 40000, 1700)
    assert s["test"]["latest"]["win_rate"] == 0.8 and s["test"]["best"]["win_rate"] == 0.75
    assert s["test"]["latest coef=1.5"]["win_rate"] == 0.6
    assert s["validation"] == [[500, 0.5]]
    assert s["config"] == {"alg": "vdn", "level": "easy", "seed": 3, "arena": {"n_blue": 3}}


def test_a_run_extended_after_its_test_reports_its_last_test(tmp_path: Path) -> None:
    """A run resumed with more episodes is tested again: counters and figures of that test."""
    run = _run(tmp_path)
    with (run / "eval.csv").open() as f:
        first = list(csv.DictReader(f))
    again = [{**r, "episodes": 1300, "env_steps": 52000, "win_rate": 0.9}
             for r in first if r["split"] == "test" and r["contexts"] == "main"]  # fmt: skip
    _write(run / "eval.csv", EVAL_COLUMNS, first + again)
    s = summarize("var", run)
    assert (s["episodes"], s["env_steps"]) == (1300, 52000)
    assert set(s["test"]) == {"latest", "best"}  # the first test's extra context is not this one's
    assert s["test"]["latest"]["win_rate"] == 0.9


def test_an_unfinished_run_is_refused_by_name(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no test rows"):
        summarize("var", _run(tmp_path, finished=False))


def test_main_writes_json_with_the_snapshot_commit(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("NEURONSMAE_COMMIT", "abc123")
    out = tmp_path / "data" / "x.json"
    assert main([f"var={_run(tmp_path)}", "--out", str(out), "--note", "a test"]) == 0
    payload = json.loads(out.read_text())
    assert payload["commit"] == "abc123" and payload["what"] == "a test"
    assert payload["runs"][0]["name"] == "var"
    assert "| var | 900 | 40000 | 0.800 | 0.750 |" in capsys.readouterr().out


def test_bad_runs_and_outputs_are_usage_errors_naming_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each of these was a traceback, or (a NAME twice) went into the JSON unseen."""
    run = _run(tmp_path)
    (tmp_path / "u").mkdir()
    unfinished = _run(tmp_path / "u", finished=False)
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "config.json").write_text("{not json")
    out = str(tmp_path / "s.json")
    cases = [
        ([f"a={tmp_path / 'nowhere'}", "--out", out], "nowhere/config.json"),
        ([f"a={broken}", "--out", out], "broken/config.json is not a run's configuration"),
        ([f"a={unfinished}", "--out", out], "no test rows"),
        ([f"a={run}", f"a={run}", "--out", out], "given twice: ['a']"),
        ([f"={run}", "--out", out], "each run is NAME=RUN_DIR"),
        ([f"a={run}", "--out", str(tmp_path)], "--out must name a .json file"),
    ]
    for argv, said in cases:
        with pytest.raises(SystemExit) as exc:
            main(argv)
        assert exc.value.code == 2
        assert said in capsys.readouterr().err
    assert not Path(out).exists()


def test_an_existing_out_is_kept_unless_force_is_given(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """An earlier summary was replaced silently."""
    monkeypatch.setenv("NEURONSMAE_COMMIT", "abc123")
    run = _run(tmp_path)
    out = tmp_path / "keep.json"
    out.write_text('{"an": "earlier summary"}')
    with pytest.raises(SystemExit) as exc:
        main([f"a={run}", "--out", str(out)])
    assert exc.value.code == 2
    assert f"--out {out} exists; choose another file, or pass --force" in capsys.readouterr().err
    assert json.loads(out.read_text()) == {"an": "earlier summary"}
    assert main([f"a={run}", "--out", str(out), "--force"]) == 0
    assert json.loads(out.read_text())["runs"][0]["name"] == "a"
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def _broken(tmp_path: Path, how: str) -> Path:
    """A finished run with one defect ``how``."""
    run = _run(tmp_path)
    if how == "header-only train.csv":
        _write(run / "train.csv", TRAIN_COLUMNS, [])
    elif how == "eval.csv without split":
        rows = list(csv.DictReader((run / "eval.csv").open()))
        columns = tuple(c for c in EVAL_COLUMNS if c != "split")
        _write(run / "eval.csv", columns, [{k: r[k] for k in columns} for r in rows])
    elif how == "only best test rows":
        rows = [r for r in csv.DictReader((run / "eval.csv").open()) if r["weights"] != "latest"]
        _write(run / "eval.csv", EVAL_COLUMNS, rows)
    elif how == "non-numeric cell":
        rows = list(csv.DictReader((run / "eval.csv").open()))
        rows[1]["win_rate"] = "abc"
        _write(run / "eval.csv", EVAL_COLUMNS, rows)
    elif how == "non-UTF-8 train.csv":
        (run / "train.csv").write_bytes(b"updates,wall_seconds\n\xff\xfe,1\n")
    elif how == "config.json a list":
        (run / "config.json").write_text("[1, 2]")
    return run


@pytest.mark.parametrize(
    ("how", "said"),
    [
        ("header-only train.csv", "train.csv has no rows"),
        ("eval.csv without split", "eval.csv lacks the column(s) ['split']"),
        ("only best test rows", "eval.csv has no test row of the final weights"),
        ("non-numeric cell", "eval.csv line 3, column 'win_rate': expected a number, got 'abc'"),
        ("non-UTF-8 train.csv", "train.csv is not a records CSV"),
        ("config.json a list", "config.json is not a run's configuration: not an object"),
    ],
)
def test_a_malformed_run_is_a_usage_error_naming_the_file(
    how: str, said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Each was a traceback (IndexError, KeyError, a ValueError naming no file)."""
    run = _broken(tmp_path, how)
    out = tmp_path / "s.json"
    with pytest.raises(SystemExit) as exc:
        main([f"a={run}", "--out", str(out)])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"{run}/{said}" in err or (said in err and str(run) in err)
    assert not out.exists()


def test_an_out_in_an_unwritable_place_is_refused_before_reading_runs(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    (tmp_path / "file").write_text("a file")
    with pytest.raises(SystemExit):
        main([f"a={tmp_path / 'nowhere'}", "--out", str(tmp_path / "file" / "s.json")])
    assert f"{tmp_path / 'file'} is a file, not a folder" in capsys.readouterr().err
