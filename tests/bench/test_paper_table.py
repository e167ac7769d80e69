"""The paper-table runner on a tiny budget: one record per run, resume, skip when done."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bench.paper_table import main
from neuronsmae.trainers.run.config import make_config, preset
from neuronsmae.trainers.run.train import train

pytestmark = [pytest.mark.ray, pytest.mark.slow, pytest.mark.usefixtures("local_ray")]

TINY = [
    "episodes=40", "agent_hidden=16", "mixer_embed=8", "batch_size=200", "eval_every=20",
    "eval_episodes=2", "final_eval_episodes=3", "envs_per_worker=5", "checkpoint_every=20",
    "updates_per_round=2", "iteration_episodes=10",
]  # fmt: skip


def test_the_table_resumes_a_stopped_run_records_it_and_skips_it_next_time(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, out = tmp_path / "runs", tmp_path / "table.json"
    sets = [arg for kv in TINY for arg in ("--set", kv)]
    args = ["--algs", "qmix", "--levels", "hard", "--seeds", "3", "--workers", "2"]
    args += ["--runs", str(runs), "--out", str(out), *sets]
    # A run stopped half-way: 20 of its 40 episodes, checkpointed, not recorded.
    half = make_config(preset("paper"), dict(kv.split("=") for kv in TINY), {
        "alg": "qmix", "level": "hard", "seed": 3, "workers": 2, "env": "inprocess",
        "episodes": 20, "out": str(runs / "paper" / "qmix_hard_s3"), "progress": False,
    })  # fmt: skip
    train(half)
    assert main(args) == 0
    assert "resuming" in capsys.readouterr().out
    (line,) = json.loads(out.read_text())["records"]
    assert (line["alg"], line["level"], line["seed"], line["learner"]) == (
        "qmix",
        "hard",
        3,
        "paper",
    )
    # 4 iterations of 10 episodes, each max(2, 2·⌊stored / 200⌋) updates of 200 (the
    # resumed half starts with the first half's replay, saved beside its checkpoint)
    assert line["episodes"] == 40 and line["env_steps"] > 0 and line["iterations"] == 4
    assert line["updates"] > 4 * 2  # more than the floor once 400 transitions are stored
    assert line["samples"] == 200 * line["updates"]  # ≥ 200 transitions from the first
    assert (line["win_rule"], line["contexts"]) == ("released", "Friction_coeff=0.5;coef=0.5")
    assert line["test_contexts"] == {
        "main": {"level": "hard", "Friction_coeff": 0.5, "coef": 1.5},
        "coef=1.0": {"level": "hard", "Friction_coeff": 0.5, "coef": 1.0},
    }
    assert set(line["test"]) == {"main", "coef=1.0"}
    main_test = line["test"]["main"]
    assert main_test["episodes"] == 3 and 0 <= main_test["released_win_rate"] <= 1
    assert line["commit"] and line["wall_minutes"] > 0
    assert line["logs"] == "table_runs/paper/qmix_hard_s3"  # relative to the table's folder
    logs = out.parent / line["logs"]  # what neuronsmae-plot needs, kept beside the table
    assert sorted(p.name for p in logs.iterdir()) == ["config.json", "eval.csv", "train.csv"]
    assert main(args) == 0  # already recorded: skipped, nothing added
    assert len(json.loads(out.read_text())["records"]) == 1
    assert "| hard | QMIX | 0.34 | 0." in capsys.readouterr().out  # the table, the run in it
    # Tested again at its own test contexts: that is the main test, its figures copied.
    assert main([*args, "--test-at", "coef=1.5"]) == 0
    assert main([*args, "--test-at", "coef=1.5"]) == 0  # already there: not tested again
    assert "0 record(s) tested" in capsys.readouterr().out
    (line,) = json.loads(out.read_text())["records"]
    assert line["test"]["coef=1.5"] == line["test"]["main"]
    assert line["test_contexts"]["coef=1.5"] == line["test_contexts"]["main"]
    # Another bot: the run's level gives way (it was overridden by the record's before).
    assert main([*args, "--test-at", "level=random"]) == 0
    (line,) = json.loads(out.read_text())["records"]
    assert line["test_contexts"]["level=random"] == {
        "level": "random",
        "Friction_coeff": 0.5,
        "coef": 1.5,
    }
    assert "at {'level': 'random'" in capsys.readouterr().out
    # Tested again from the checkpoint: the same starts and weights, the same figures.
    first = line["test"].pop("level=random")
    out.write_text(json.dumps({"records": [line]}))
    assert main([*args, "--test-at", "level=random"]) == 0
    assert json.loads(out.read_text())["records"][0]["test"]["level=random"] == first
    assert main([*args, "--report"]) == 0
    head = "| released rule, coef 1.5 | released rule, coef 1.5 | released rule, against random |"
    assert head in capsys.readouterr().out


def test_a_run_finished_but_not_recorded_is_recorded_without_training_again(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Stopped between the run's final test and its record, the table refused the cell on
    every later command ("finished its 40 episodes")."""
    import bench.paper_table as table_module

    runs, out = tmp_path / "runs", tmp_path / "table.json"
    sets = [arg for kv in TINY for arg in ("--set", kv)]
    args = ["--algs", "vdn", "--levels", "easy", "--seeds", "2", "--workers", "2"]
    args += ["--runs", str(runs), "--out", str(out), *sets]
    real = table_module.keep_logs

    def disk_full(*a: object) -> Path:
        raise OSError("No space left on device")

    monkeypatch.setattr(table_module, "keep_logs", disk_full)
    with pytest.raises(OSError, match="No space"):
        main(args)
    assert not out.exists()
    run_dir = runs / "paper" / "vdn_easy_s2"
    before = (run_dir / "checkpoint.pt").stat().st_mtime_ns
    monkeypatch.setattr(table_module, "keep_logs", real)
    assert main(args) == 0
    assert "recording" in capsys.readouterr().out
    assert (run_dir / "checkpoint.pt").stat().st_mtime_ns == before  # not trained again
    (line,) = json.loads(out.read_text())["records"]
    assert line["episodes"] == 40 and set(line["test"]) == {"main", "coef=1.0"}
    with (run_dir / "eval.csv").open() as f:
        import csv

        final = [r for r in csv.DictReader(f) if r["split"] == "test" and r["weights"] == "latest"
                 and r["contexts"] == "main"]  # fmt: skip
    assert line["test"]["main"]["win_rate"] == float(final[-1]["win_rate"])
    assert line["test"]["main"]["episodes"] == 3


def test_the_dr_coef_variant_trains_on_the_released_coefs_and_is_tested_as_released(
    tmp_path: Path,
) -> None:
    import csv

    runs, out = tmp_path / "runs", tmp_path / "table.json"
    sets = [arg for kv in [*TINY, "episodes=20"] for arg in ("--set", kv)]
    assert main(["--learner", "paper_dr", "--levels", "easy", "--seeds", "1", "--workers", "2",
                 "--runs", str(runs), "--out", str(out), *sets]) == 0  # fmt: skip
    (line,) = json.loads(out.read_text())["records"]
    assert (line["learner"], line["alg"], line["preset"]) == ("paper_dr", "vdn", "paper")
    assert line["contexts"] == "Friction_coeff=0.5;coef=0.5,0.7,1,1.4,1.7,2"
    assert line["test_contexts"]["main"] == {"level": "easy", "Friction_coeff": 0.5, "coef": 1.5}
    with open(runs / "paper_dr" / "vdn_easy_s1" / "episodes.csv", newline="") as f:
        coefs = {json.loads(row["contexts"])["coef"] for row in csv.DictReader(f)}
    assert coefs <= {0.5, 0.7, 1, 1.4, 1.7, 2} and len(coefs) > 1  # drawn per episode
