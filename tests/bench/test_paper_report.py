"""The paper table's report: mean and 95 % interval over seeds, missing cells and seeds."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest

from bench.paper_report import interval, report
from bench.paper_table import DR_COEF_CONTEXTS, cell_config, main, set_aside


def _record(alg: str, level: str, seed: int, rate: float, learner: str = "paper") -> dict:
    test: dict[str, Any] = {}
    if learner in ("paper", "paper_dr"):  # coef 1.5 (main) and coef 1.0, the released rule
        # beside the referee
        test["main"] = {"released_win_rate": rate / 2, "win_rate": rate / 2,
                        "draw_rate": 0.0, "loss_rate": 1 - rate / 2}  # fmt: skip
        test["coef=1.0"] = {"released_win_rate": rate, "win_rate": rate}
    else:
        test["main"] = {"win_rate": rate}
    return {"alg": alg, "level": level, "seed": seed, "learner": learner, "test": test,
            "episodes": 30_000, "env_steps": 1_480_000, "wall_minutes": 30.0,
            "updates": 280_000, "samples": 560_000_000}  # fmt: skip


def test_interval_is_the_student_t_half_width_over_seeds() -> None:
    mean, half = interval([0.5, 0.6, 0.7])
    assert mean == pytest.approx(0.6)
    # t(0.975, 2) = 4.3027; the standard error of (0.5, 0.6, 0.7) is 0.1 / sqrt(3)
    assert half == pytest.approx(4.3027 * 0.1 / math.sqrt(3), rel=1e-4)
    assert interval([0.4]) == (0.4, None)


def _rows(text: str) -> dict[tuple[str, str], list[str]]:
    return {
        tuple(c.strip() for c in line.split("|")[1:3]): [c.strip() for c in line.split("|")]
        for line in text.splitlines()
        if line.startswith("| ") and not line.startswith("| level")
    }


def test_report_lists_every_cell_marks_missing_seeds_and_counts_compute() -> None:
    records = [_record("vdn", "easy", s, r) for s, r in ((1, 0.5), (2, 0.6), (3, 0.7))]
    records += [_record("iql", "hard", 2, 0.5), _record("vdn", "easy", 1, 0.9, "defaults")]
    text = report({"records": records})
    paper = text.split("This project's learner")[0]
    rows = _rows(paper)
    assert len(rows) == 11  # three levels × three algorithms, then VDN at levels 0 and 1
    vdn = rows[("easy", "VDN")]
    assert vdn[3] == "0.93"  # the paper's figure
    assert vdn[4].startswith("0.300 ± 0.124 (s1 0.250, s2 0.300, s3 0.350)")  # coef 1.5
    assert vdn[5] == "0.300 / 0.000 / 0.700"  # the referee's outcomes at coef 1.5
    assert vdn[6].startswith("0.600 ± 0.248")  # the released rule at coef 1.0
    assert rows[("hard", "IQL")][4] == "0.250 (s2 0.250; 1 of 3 seeds)"
    assert rows[("middle", "QMIX")].count("—") == 3
    assert rows[("1", "VDN")][3] == "—"  # the paper has no figure for the released levels
    own = _rows(text.split("This project's learner")[1].split("Compute")[0])
    assert own[("easy", "VDN")][4] == "0.900 (s1 0.900; 1 of 3 seeds)"
    compute = text.split("Compute:")[1]
    assert "paper: 4 of 29 runs recorded, 120,000 training episodes (5.9 million" in compute
    assert "1,120,000 gradient updates on 2,240 million sampled transitions, 2.0 h" in compute
    assert "defaults: 1 of 9 runs recorded" in compute
    # A record written before runs counted their sampled transitions claims none of them.
    del records[-1]["samples"]
    compute = report({"records": records}).split("Compute:")[1]
    assert "defaults: 1 of 9 runs recorded" in compute
    assert "280,000 gradient updates, 0.5 h" in compute
    assert "This project's learner" not in report({"records": records[:4]})


def test_report_says_whether_the_papers_orderings_hold() -> None:
    rates = {("easy", "vdn"): 0.9, ("middle", "vdn"): 0.6, ("hard", "vdn"): 0.4,
             ("easy", "qmix"): 0.8, ("middle", "qmix"): 0.7, ("hard", "qmix"): 0.75,
             ("easy", "iql"): 0.5, ("middle", "iql"): 0.3, ("hard", "iql"): 0.2}  # fmt: skip
    records = [_record(alg, level, 1, 2 * r) for (level, alg), r in rates.items()]
    text = report({"records": records})
    assert "- VDN: easy, middle, hard 0.900, 0.600, 0.400: easy > middle > hard holds" in text
    assert "- QMIX: easy, middle, hard 0.800, 0.700, 0.750: easy > middle > hard does not" in text
    assert "- easy: VDN 0.900, QMIX 0.800, IQL 0.500: VDN ≥ QMIX > IQL holds" in text
    assert "- hard: VDN 0.400, QMIX 0.750, IQL 0.200: VDN ≥ QMIX > IQL does not hold" in text
    assert "at the training context" not in text  # no run re-tested at coef 0.5 yet


def test_report_says_whether_the_orderings_hold_at_the_training_context() -> None:
    """The re-tests at coef 0.5 (``--test-at coef=0.5``) get the orderings of their own,
    from their own means, beside those of the released test (coef 1.5)."""
    at_15 = {"iql": 0.285, "vdn": 0.235, "qmix": 0.04}
    at_05 = {"iql": 0.99, "vdn": 0.935, "qmix": 0.99}
    records = []
    for alg in at_15:
        rec = _record(alg, "easy", 1, 2 * at_15[alg])
        rec["test"]["coef=0.5"] = {"released_win_rate": at_05[alg], "win_rate": at_05[alg]}
        records.append(rec)
    text = report({"records": records})
    released, trained = text.split("at the training context")
    assert "- easy: VDN 0.235, QMIX 0.040, IQL 0.285: VDN ≥ QMIX > IQL does not hold" in released
    assert "- easy: VDN 0.935, QMIX 0.990, IQL 0.990: VDN ≥ QMIX > IQL does not hold" in trained
    assert "easy > middle > hard" not in text  # one level recorded: no level ordering


def test_main_counts_the_seeds_recorded_beside_those_asked_for(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "table.json"
    records = [_record("vdn", "easy", s, 0.5) for s in (1, 2, 3)]
    out.write_text(json.dumps({"records": records}))
    assert main(["--report", "--seeds", "1", "--out", str(out)]) == 0
    assert "paper: 3 of 29 runs recorded" in capsys.readouterr().out


def test_tests_added_later_get_their_own_table_and_none_without_them() -> None:
    records = [_record("vdn", "easy", s, r) for s, r in ((1, 0.6), (2, 0.8))]
    assert "coef=0.5" not in report({"records": records})
    records[0]["test"]["coef=0.5"] = {"released_win_rate": 1.0}
    lines = report({"records": records}).splitlines()
    head = "| level | alg | released rule, coef 1.5 | released rule, coef 0.5 |"
    assert head in lines
    row = next(line for line in lines[-11:] if line.startswith("| easy | VDN"))
    assert row.split("|")[3].strip().startswith("0.350 ±")  # both seeds at coef 1.5
    assert row.split("|")[4].strip() == "1.000 (s1 1.000; 1 of 2 seeds)"  # s2 not yet
    assert lines[-1].startswith("| 1 | VDN | — | — |")
    records[1]["test"]["level=1"] = {"released_win_rate": 0.1}  # another bot, tested later
    head += " released rule, against 1 |"  # a column named by its bot
    assert head in report({"records": records}).splitlines()
    records[1]["test"]["level=hard"] = {"released_win_rate": 0.0}
    records[0]["test"]["level=easy"] = {"released_win_rate": 0.7}  # tested after hard
    records[0]["test"]["coef=1.4"] = {"released_win_rate": 0.5}  # a context, tested last
    head = head.replace(" released rule, against 1 |", " released rule, coef 1.4 |")
    head += " released rule, against 1 | released rule, against easy |"
    assert head + " released rule, against hard |" in report({"records": records}).splitlines()


def test_a_retest_against_the_runs_own_bot_is_its_main_test_and_needs_no_checkpoint(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # A run whose checkpoint is gone: against its own bot, at its own contexts, the re-test
    # is its main test; anything else needs the weights and is skipped.
    line = _record("vdn", "easy", 1, 0.6)
    line["run_dir"] = str(tmp_path / "gone")
    main_contexts = {"level": "easy", "Friction_coeff": 0.5, "coef": 1.5}
    line["test_contexts"] = {"main": main_contexts}
    out = tmp_path / "table.json"
    out.write_text(json.dumps({"records": [line]}))
    args = ["--out", str(out), "--runs", str(tmp_path / "runs")]
    assert main([*args, "--test-at", "level=easy;coef=1.5"]) == 0
    assert "1 record(s) tested" in capsys.readouterr().out
    (line,) = json.loads(out.read_text())["records"]
    assert line["test"]["level=easy;coef=1.5"] == line["test"]["main"]
    assert line["test_contexts"]["level=easy;coef=1.5"] == main_contexts
    assert main([*args, "--test-at", "level=hard"]) == 0  # another bot: the weights needed
    assert "no checkpoint for vdn/easy/s1: skipped" in capsys.readouterr().out


@pytest.mark.parametrize("key", ["seed=7", "alg=qmix", "level=hard", "out=elsewhere"])
def test_set_cannot_change_what_names_a_cell(
    key: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # --set seed=7 trained every seed's cell with seed 7 and recorded them as s1, s2, ...
    with pytest.raises(SystemExit) as stop:
        main(["--out", str(tmp_path / "t.json"), "--runs", str(tmp_path), "--set", key])
    assert stop.value.code == 2
    assert f"--set {key.split('=')[0]}: the table sets these per cell" in capsys.readouterr().err


def test_a_run_folder_that_cannot_be_resumed_is_set_aside_never_deleted(tmp_path: Path) -> None:
    run = tmp_path / "vdn_easy_s1"
    run.mkdir()
    (run / "NOTES.txt").write_text("mine")
    first = set_aside(run)
    run.mkdir()
    second = set_aside(run)  # twice within a second: another name
    assert not run.exists() and first != second
    assert (first / "NOTES.txt").read_text() == "mine" and second.name.startswith(run.name)


@pytest.mark.parametrize(
    ("argv", "said"),
    [(["--test-at", ""], "give at least one KEY=VALUE"),  # it trained the whole table
     (["--test-at", "bogus=1"], "unknown context key 'bogus'"),  # a traceback after loading
     (["--report", "--test-at", "coef=0.5"], "--report and --test-at are alternatives")],
)  # fmt: skip
def test_test_at_is_checked_before_anything_runs(
    argv: list[str], said: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as stop:
        main([*argv, "--out", str(tmp_path / "t.json"), "--runs", str(tmp_path / "runs")])
    assert stop.value.code == 2 and said in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_the_dr_coef_variant_has_its_own_rows_beside_the_fixed_coef_cells() -> None:
    records = [_record("vdn", "easy", 1, 0.4), _record("vdn", "easy", 1, 0.8, "paper_dr")]
    records.append(_record("vdn", "1", 1, 0.6, "paper_dr"))
    text = report({"records": records})
    assert "This project's learner" not in text  # paper_dr is the paper preset's variant
    dr = _rows(text.split("`--dr_coef` (coef drawn")[1].split("Compute")[0])
    assert list(dr) == [("easy", "VDN"), ("1", "VDN")]  # only the cells it ran
    assert dr[("easy", "VDN")][3:7] == [
        "0.200 (s1 0.200; 1 of 3 seeds)",  # the same cell trained at coef 0.5
        "0.400 (s1 0.400; 1 of 3 seeds)",  # trained at coef 0.5-2
        "0.400 / 0.000 / 0.600",
        "0.800 (s1 0.800; 1 of 3 seeds)",  # coef 1.0
    ]
    assert dr[("1", "VDN")][3] == "—"
    assert "- paper_dr: 2 of 2 runs recorded" in text
    # The paper preset's table counts the fixed-coef runs only.
    assert _rows(text.split("`--dr_coef` (coef drawn")[0])[("easy", "VDN")][4].startswith("0.200")


def test_the_dr_coef_variant_trains_the_paper_preset_at_the_released_coef_list(
    tmp_path: Path,
) -> None:
    import argparse

    args = argparse.Namespace(learner="paper_dr", workers=2, env="inprocess", torch_threads=1,
                              set=[], minutes=30.0)  # fmt: skip
    cfg = cell_config(args, "vdn", "1", 1, tmp_path)
    plain = cell_config(argparse.Namespace(**{**vars(args), "learner": "paper"}), "vdn", "1", 1,
                        tmp_path)  # fmt: skip
    assert cfg.contexts == DR_COEF_CONTEXTS == "Friction_coeff=0.5;coef=0.5,0.7,1,1.4,1.7,2"
    assert plain.contexts == "Friction_coeff=0.5;coef=0.5"
    assert cfg.eval == plain.eval and cfg.learner == plain.learner  # tested and learned alike


def test_the_like_for_like_row_expects_one_seed_a_level() -> None:
    """#42's like-for-like row (the project's VDN trained at the released contexts, tested
    as released) is one seed per level: a recorded seed is not "1 of 3", and its compute
    counts 3 runs, not 9."""
    like = _record("vdn", "easy", 1, 0.0, "defaults_released")
    like["test"]["main"] = {"released_win_rate": 0.61, "win_rate": 0.61}
    records = [_record("vdn", "easy", s, 0.9, "defaults") for s in (1, 2)] + [like]
    text = report({"records": records})
    row = _rows(text.split("This project's learner")[1])[("easy", "VDN")]
    assert row[4].endswith("2 of 3 seeds)")  # its own contexts: three seeds a level
    assert row[6] == "0.610 (s1 0.610)"
    assert "- defaults_released: 1 of 3 runs recorded" in text
    assert "- defaults: 2 of 9 runs recorded" in text
    second = dict(like, seed=2)  # a second seed recorded: two expected a level
    text = report({"records": [*records, second]})
    assert "- defaults_released: 2 of 6 runs recorded" in text
