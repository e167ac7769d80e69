"""A run's evaluations in marl-eval's JSON format, and the format's checks."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from neuronsmae.trainers.run.config import make_config
from neuronsmae.trainers.run.marl_eval import (
    MarlEvalFormatError,
    check_format,
    merge,
    run_json,
    task_name,
)
from neuronsmae.trainers.run.records import EVAL_COLUMNS


def _run(folder: Path, rows: list[dict[str, object]], **config: object) -> Path:
    folder.mkdir(parents=True)
    cfg = make_config({"progress": False, **config})
    (folder / "config.json").write_text(json.dumps(cfg.to_dict()))
    with (folder / "eval.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=EVAL_COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({"weights": "latest", "contexts": "main", "draw_rate": 0,
                             "loss_rate": 0, "eval_episodes": 50, "updates": 1,
                             "wall_seconds": 1, "released_win_rate": 0.0, **row})  # fmt: skip
    return folder


def test_a_runs_validations_are_the_steps_and_its_test_the_absolute_metrics(
    tmp_path: Path,
) -> None:
    rows = [
        {"episodes": 500, "env_steps": 24000, "split": "validation", "win_rate": 0.4,
         "mean_return": 1.5},
        {"episodes": 1000, "env_steps": 48000, "split": "validation", "win_rate": 0.7,
         "mean_return": 9.0},
        {"episodes": 1000, "env_steps": 48000, "split": "test", "win_rate": 0.8,
         "mean_return": 12.0},
        {"episodes": 1000, "env_steps": 48000, "split": "test", "win_rate": 0.1,
         "mean_return": -5.0, "contexts": "coef=1.5"},
    ]  # fmt: skip
    doc = run_json(_run(tmp_path / "r", rows, alg="qmix", seed=3))
    check_format(doc)
    run = doc["neuronsmae"]["coop_abstract_easy"]["qmix"]["seed_3"]
    assert run["step_0"] == {"step_count": 24000, "win_rate": [0.4], "return": [1.5]}
    assert run["step_1"]["step_count"] == 48000
    assert run["absolute_metrics"] == {"win_rate": [0.8], "return": [12.0]}  # main contexts


def test_the_released_rule_is_the_metric_of_a_run_that_reports_it(tmp_path: Path) -> None:
    rows = [{"episodes": 20, "env_steps": 1000, "split": "test", "win_rate": 0.5,
             "released_win_rate": 0.25, "mean_return": 0.0}]  # fmt: skip
    doc = run_json(_run(tmp_path / "r", rows, **{"eval.win_rule": "released"}), "vdn (paper)")
    assert doc["neuronsmae"]["coop_abstract_easy"]["vdn (paper)"]["seed_1"] == {
        "absolute_metrics": {"win_rate": [0.25], "return": [0.0]}
    }


def test_task_names_follow_the_benchmarl_family() -> None:
    assert task_name({"level": "hard"}) == "coop_abstract_hard"
    assert task_name({"arena": {"action_space": "discrete"}, "level": "1"}) == "coop_discrete_1"
    assert task_name({"arena": {"n_blue": 3, "n_red": 3}}) == "coop_3v3_easy"
    assert task_name({"arena": {"n_blue": 1, "n_red": 1}}) == "coop_abstract_1v1_easy"


def test_merge_joins_runs_and_the_checks_name_what_is_wrong() -> None:
    a = {"neuronsmae": {"t": {"vdn": {"seed_1": {"absolute_metrics": {"win_rate": [1.0]}}}}}}
    b = {"neuronsmae": {"t": {"vdn": {"seed_2": {"absolute_metrics": {"win_rate": [0.0]}}}}}}
    merged = merge([a, b])
    assert sorted(merged["neuronsmae"]["t"]["vdn"]) == ["seed_1", "seed_2"]
    check_format(merged)
    bad = json.loads(json.dumps(a))
    bad["neuronsmae"]["t"]["vdn"]["seed_1"]["step_0"] = {"win_rate": [0.5]}
    with pytest.raises(MarlEvalFormatError, match="integer step_count"):
        check_format(bad)
    bad["neuronsmae"]["t"]["vdn"]["seed_1"]["step_0"] = {"step_count": 5, "loss": [0.5]}
    with pytest.raises(MarlEvalFormatError, match="metrics"):
        check_format(bad)
    with pytest.raises(MarlEvalFormatError, match="list of numbers"):
        check_format({"e": {"t": {"a": {"r": {"absolute_metrics": {"win_rate": "0.5"}}}}}})
