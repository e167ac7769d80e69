"""bench.bench_learning: every setting, the run folder and the report's folder are checked
before training starts, as usage errors."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from bench import bench_learning
from neuronsmae.trainers.run.config import TrainConfig
from neuronsmae.trainers.run.interrupt import TrainingInterrupted


@pytest.fixture
def no_training(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bench_learning, "train", lambda *a, **k: pytest.fail("trained"))


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    assert bench_learning.main(argv) == 2
    return capsys.readouterr().err


@pytest.mark.usefixtures("no_training")
def test_bad_overrides_are_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    """Each was a ConfigError traceback."""
    assert "unknown config key 'foo' in --set" in _refused(["--set", "foo=1"], capsys)
    assert "--set: lr must be > 0, got -1.0" in _refused(["--set", "lr=-1"], capsys)
    assert "--set out= needs a folder" in _refused(["--set", "out="], capsys)


@pytest.mark.usefixtures("no_training")
def test_a_run_folder_holding_a_run_is_refused_without_naming_a_missing_flag(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """It was a RunExistsError traceback telling to pass --resume, which the bench lacks."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    err = _refused(["--set", f"out={run}"], capsys)
    assert f"--set out={run}: that folder already holds a run" in err
    assert "pass --resume" not in err and "give another out" in err
    (tmp_path / "file").write_text("a file")
    err = _refused(["--set", f"out={tmp_path / 'file' / 'run'}"], capsys)
    assert f"{tmp_path / 'file'} is a file, not a folder" in err


@pytest.mark.usefixtures("no_training")
def test_an_out_that_is_a_file_or_unwritable_is_refused_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """An existing file as --out ended in FileExistsError after the whole run."""
    keep = tmp_path / "keep.gif"
    keep.write_bytes(b"GIF89a")
    run = ["--set", f"out={tmp_path / 'run'}"]
    assert f"--out {keep}: " in _refused([*run, "--out", str(keep)], capsys)
    assert keep.read_bytes() == b"GIF89a"
    assert "--out /proc/lg: cannot create the folder" in _refused(
        [*run, "--out", "/proc/lg"], capsys
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.gif"]  # nothing left behind


def test_a_good_setting_reaches_training_and_a_stopped_run_writes_no_report(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    seen = {}

    def stop(cfg: TrainConfig) -> None:  # a Ctrl-C: the run saved its checkpoint
        seen["cfg"] = cfg
        raise TrainingInterrupted(cfg.run_dir, 12, "SIGINT")

    monkeypatch.setattr(bench_learning, "train", stop)
    out = tmp_path / "reports"
    argv = ["--set", f"out={tmp_path / 'run'}", "--set", "lr=1e-3", "--out", str(out)]
    assert bench_learning.main(argv) == 130
    assert seen["cfg"].out == str(tmp_path / "run") and seen["cfg"].learner.lr == 1e-3
    assert "stopped at 12 episodes" in capsys.readouterr().err
    assert not out.exists() or not list(out.iterdir())  # no report of a run cut short


ROOT = Path(__file__).resolve().parents[2]


def test_the_documented_command_runs_and_no_doc_gives_the_form_that_cannot() -> None:
    """``python bench/bench_learning.py`` was documented but fails: No module named 'bench'."""
    shown = subprocess.run([sys.executable, "-m", "bench.bench_learning", "--help"], cwd=ROOT,
                           capture_output=True, text=True, timeout=300)  # fmt: skip
    assert shown.returncode == 0, shown.stderr
    assert "--set KEY=VALUE" in shown.stdout
    files = [ROOT / "README.md", *(ROOT / "docs").glob("*.md"), *(ROOT / "bench").glob("*.py"),
             *(ROOT / "trainers").rglob("*.py")]  # fmt: skip
    stale = [
        f"{f.relative_to(ROOT)}:{n}"
        for f in files
        for n, line in enumerate(f.read_text().splitlines(), start=1)
        if re.search(r"python3? bench/", line)
    ]
    assert stale == []
