"""IQM, stratified-bootstrap intervals and the probability of improvement on known scores."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.baselines_report import bootstrap, from_baselines, improvement, iqm, main, scores
from neuronsmae.trainers.run.marl_eval import check_format


def test_iqm_is_the_mean_of_the_middle_half_over_runs_and_tasks() -> None:
    per_task = {"a": np.array([0.0, 0.2, 0.4, 1.0]), "b": np.array([0.6, 0.8, 0.9, 0.1])}
    values = np.sort(np.concatenate(list(per_task.values())))  # 8 values: the middle 4
    assert iqm(per_task) == pytest.approx(values[2:6].mean())


def test_probability_of_improvement_counts_ties_as_half_and_averages_tasks() -> None:
    x = {"a": np.array([1.0, 0.5]), "b": np.array([0.2])}
    y = {"a": np.array([0.5]), "b": np.array([0.9]), "c": np.array([0.0])}
    # task a: 1.0 > 0.5 (1), 0.5 = 0.5 (1/2) → 0.75; task b: 0.2 < 0.9 → 0; c not shared
    assert improvement(x, y) == pytest.approx(0.375)
    assert improvement(x, y) + improvement(y, x) == pytest.approx(1.0)


def test_the_bootstrap_interval_holds_the_estimate_and_narrows_with_more_runs() -> None:
    rng = np.random.default_rng(0)
    few = {"a": rng.uniform(0.4, 0.8, 3)}
    many = {"a": rng.uniform(0.4, 0.8, 30)}
    lo, hi = bootstrap(iqm, (few,), reps=500)
    assert lo <= iqm(few) <= hi
    lo2, hi2 = bootstrap(iqm, (many,), reps=500)
    assert hi2 - lo2 < hi - lo


def test_baseline_records_become_marl_eval_json_and_a_report(tmp_path: Path) -> None:
    table = {"records": [
        {"algorithm": "mappo", "task": "coop_abstract", "level": "easy", "seed": s,
         "test": {"win_rate": w}} for s, w in ((1, 0.4), (2, 0.6), (3, 0.5))
    ]}  # fmt: skip
    doc = from_baselines(table)
    table["records"].append({"algorithm": "mappo", "task": "coop_continuous", "level": "easy",
                             "seed": 1, "test": {"win_rate": 0.0}})  # fmt: skip
    check_format(doc)
    got = scores(doc)
    assert list(got) == ["mappo (benchmarl)"]
    assert sorted(got["mappo (benchmarl)"]["coop_abstract_easy"]) == [0.4, 0.5, 0.6]
    run = {"neuronsmae": {"coop_abstract_easy": {"vdn": {"seed_1": {
        "step_0": {"step_count": 10, "win_rate": [0.3], "return": [1.0]},
        "absolute_metrics": {"win_rate": [0.9], "return": [20.0]}}}}}}  # fmt: skip
    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "vdn_s1.json").write_text(json.dumps(run))
    baselines = tmp_path / "b.json"
    baselines.write_text(json.dumps(table))
    out = tmp_path / "out"
    args = ["--baselines", str(baselines), "--runs", str(runs), "--reps", "200",
            "--json", str(out / "m.json"), "--summary", str(out / "s.json"),
            "--plot", str(out / "p.png")]  # fmt: skip
    assert main(args) == 0
    summary = json.loads((out / "s.json").read_text())
    rows = {(r["learner"], r["task"]): r for r in summary["iqm"]}
    assert set(rows) == {  # a task per row: continuous actions are not pooled with abstract ones
        ("mappo (benchmarl)", "coop_abstract_easy"),
        ("mappo (benchmarl)", "coop_continuous_easy"),
        ("vdn", "coop_abstract_easy"),
    }
    assert rows["mappo (benchmarl)", "coop_abstract_easy"]["iqm"] == pytest.approx(0.5)
    assert rows["mappo (benchmarl)", "coop_continuous_easy"]["iqm"] == 0.0
    assert rows["mappo (benchmarl)", "coop_abstract_easy"]["runs"] == 3
    assert {(p["x"], p["y"]) for p in summary["improvement"]} == {
        ("mappo (benchmarl)", "vdn"),
        ("vdn", "mappo (benchmarl)"),
    }
    check_format(json.loads((out / "m.json").read_text()))
    assert (out / "p.png").stat().st_size > 1000
