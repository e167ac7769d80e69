"""The progress bar follows whichever budget, episodes or minutes, ends the run; a resumed
run's records end where its checkpoint does."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import pytest

from neuronsmae.trainers.run.config_groups import ConfigError
from neuronsmae.trainers.run.records import (
    EPISODE_COLUMNS,
    EVAL_COLUMNS,
    TRAIN_COLUMNS,
    Recorder,
    RunExistsError,
    RunLock,
    budget_status,
    trim_records,
)


def test_the_wall_clock_binds_a_slow_run() -> None:
    # 30-minute budget, 10 minutes in, 2,000 of 30,000 episodes: 28,000 more would take
    # 140 minutes at this pace, the clock runs out in 20.
    status = budget_status(2_000, 30_000, 0, 600.0, 1800.0)
    assert status.binding == "time"
    assert status.fraction == pytest.approx(1 / 3)
    assert status.eta_seconds == pytest.approx(1200.0)


def test_the_episodes_bind_a_fast_run() -> None:
    # 1,000 episodes budget, 900 played in 60 s of a 30-minute budget: 7 s to go.
    status = budget_status(900, 1_000, 0, 60.0, 1800.0)
    assert status.binding == "episodes"
    assert status.fraction == pytest.approx(0.9)
    assert status.eta_seconds == pytest.approx(100 / 15)


def test_without_a_time_limit_the_episodes_bind() -> None:
    status = budget_status(50, 200, 0, 10.0, 0.0)
    assert (status.binding, status.fraction, status.eta_seconds) == ("episodes", 0.25, 30.0)
    unknown = budget_status(0, 200, 0, 0.0, 0.0)  # nothing has landed yet: no pace
    assert unknown.binding == "episodes" and math.isinf(unknown.eta_seconds)


def test_a_resumed_run_paces_on_this_session_only() -> None:
    # resumed at 10,000 of 12,000; 1,000 more in 100 s: 200 s left, under the 1,800 s left.
    status = budget_status(11_000, 12_000, 10_000, 100.0, 1900.0)
    assert status.binding == "episodes" and status.eta_seconds == pytest.approx(100.0)
    assert budget_status(10_000, 12_000, 10_000, 0.0, 1900.0).binding == "time"


def test_the_bar_names_the_binding_budget(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    recorder = Recorder(tmp_path, 30_000, 0, progress=True, max_seconds=1800.0)
    recorder.bar.mininterval = 0.0
    recorder.advance(2_000, 600.0)
    assert recorder.bar.n == 333
    assert "2,000/30,000 ep, 10:00/30:00 (time budget binds, ETA 20:00)" in recorder.bar.desc
    recorder.close()
    assert "time budget binds" in capsys.readouterr().err


def _write(path: Path, columns: tuple[str, ...], rows: list[dict[str, object]]) -> None:
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)


def _column(path: Path, name: str) -> list[str]:
    with path.open(newline="") as f:
        return [row[name] for row in csv.DictReader(f)]


@pytest.fixture
def killed_run(tmp_path: Path) -> Path:
    """The records of a run killed at episode 10, its last checkpoint at 6 (after the
    validation and the test at 6), the last episode row cut short by the kill."""
    _write(tmp_path / "train.csv", TRAIN_COLUMNS, [{"episodes": k} for k in range(2, 11, 2)])
    evals = [{"episodes": 3, "split": "validation"}, {"episodes": 6, "split": "validation"},
             {"episodes": 6, "split": "test"}, {"episodes": 9, "split": "validation"}]  # fmt: skip
    _write(tmp_path / "eval.csv", EVAL_COLUMNS, evals)
    _write(tmp_path / "episodes.csv", EPISODE_COLUMNS,
           [{"episode": k, "seed": 100 + k, "contexts": "{}"} for k in range(1, 11)])  # fmt: skip
    with (tmp_path / "episodes.csv").open("a") as f:
        f.write("11,11")
    return tmp_path


def test_a_resumed_run_drops_the_rows_written_after_its_checkpoint(killed_run: Path) -> None:
    assert trim_records(killed_run, 6) == 2 + 1 + 5
    assert _column(killed_run / "train.csv", "episodes") == ["2", "4", "6"]
    assert _column(killed_run / "eval.csv", "split") == ["validation", "validation", "test"]
    assert _column(killed_run / "episodes.csv", "episode") == [str(k) for k in range(1, 7)]
    assert _column(killed_run / "episodes.csv", "seed") == [str(100 + k) for k in range(1, 7)]
    assert trim_records(killed_run, 6) == 0  # nothing left to drop
    assert not list(killed_run.glob("*.tmp"))


def test_a_run_resumed_for_its_final_evaluation_drops_that_evaluation_too(
    killed_run: Path,
) -> None:
    trim_records(killed_run, 6, redo_final=True)
    assert _column(killed_run / "eval.csv", "split") == ["validation", "validation"]
    assert _column(killed_run / "train.csv", "episodes") == ["2", "4", "6"]


def test_trimming_a_run_without_records_is_a_no_op(tmp_path: Path) -> None:
    assert trim_records(tmp_path, 0) == 0 and not list(tmp_path.iterdir())


def test_one_process_at_a_time_trains_in_a_run_directory(tmp_path: Path) -> None:
    # Two runs started at once into one --out both passed the check for another run's
    # files (written only later) and interleaved their records.
    first = RunLock(tmp_path / "run")
    held = rf"in use: another training process \(pid {os.getpid()}\)"
    with pytest.raises(RunExistsError, match=held):
        RunLock(tmp_path / "run")
    first.release()
    first.release()  # idempotent
    RunLock(tmp_path / "run").release()  # free again
    (tmp_path / "file").write_text("")
    with pytest.raises(ConfigError, match="cannot be created"):
        RunLock(tmp_path / "file" / "run")
