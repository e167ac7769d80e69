"""Summarise finished training runs into one JSON for docs/data, and print their table.

``python -m bench.summarize_runs NAME=RUN_DIR... --out docs/data/NAME.json [--note TEXT] [--force]``

Each ``RUN_DIR`` is a finished ``neuronsmae-train`` run directory. The summary takes from
its ``config.json`` the settings that name the run, from ``eval.csv`` the greedy
validation curve and the test figures (200 held-out episodes, final and best-validated
weights, one row per test context set), and from ``train.csv`` the learner's counters, so a
document quotes a run that is gone from disk. The commit the runs were made from is
``NEURONSMAE_COMMIT`` when set (as for runs made from a ``git archive`` snapshot), else
this checkout's ``git rev-parse HEAD``. An existing ``--out`` is replaced only with
``--force`` (the benches' output convention, :mod:`bench.common`).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

from bench.common import add_out, commit, machine, out_problem, table, write_out
from neuronsmae.trainers.run.records import read_records

CONFIG_KEYS = ("alg", "level", "seed", "workers", "env", "envs_per_worker", "max_minutes",
               "opponent", "preset", "contexts", "arena", "selfplay")  # fmt: skip
"""The configuration fields a summary keeps: those that tell the runs of a table apart."""
EVAL_NEEDS = ("episodes", "env_steps", "win_rate", "draw_rate", "loss_rate", "mean_return",
              "eval_episodes", "split", "weights", "contexts")  # fmt: skip
TRAIN_NEEDS = ("updates", "wall_seconds")
"""The columns of ``eval.csv`` and ``train.csv`` a summary reads."""


def _number(path: Path, rows: list[dict[str, str]], row: dict[str, str], column: str,
            kind: type = float) -> Any:  # fmt: skip
    """``row[column]`` as ``kind``, or a ValueError naming the file, line and column."""
    try:
        return kind(float(row[column])) if kind is int else kind(row[column])
    except (TypeError, ValueError, OverflowError):
        line = rows.index(row) + 2  # the header is line 1
        raise ValueError(
            f"{path} line {line}, column {column!r}: expected a number, got {row[column]!r}"
        ) from None


def summarize(name: str, run_dir: Path) -> dict[str, Any]:
    """The summary of one finished run: its settings, counters, test figures and curve."""
    try:
        config = json.loads((run_dir / "config.json").read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{run_dir}/config.json is not a run's configuration: {exc}") from None
    if not isinstance(config, dict):
        raise ValueError(f"{run_dir}/config.json is not a run's configuration: not an object")
    evals_csv, train_csv = run_dir / "eval.csv", run_dir / "train.csv"
    evals = read_records(evals_csv, EVAL_NEEDS)
    tests = [r for r in evals if r["split"] == "test"]
    if not tests:
        raise ValueError(f"{run_dir}: eval.csv has no test rows; the run did not finish")
    # A run resumed with a larger budget is tested again at its new end: its last test wins.
    last = max(_number(evals_csv, evals, r, "episodes", int) for r in tests)
    tests = [r for r in tests if _number(evals_csv, evals, r, "episodes", int) == last]
    if not any(r["weights"] == "latest" and r["contexts"] == "main" for r in tests):
        raise ValueError(
            f"{evals_csv} has no test row of the final weights (weights 'latest', contexts "
            "'main'); the run did not finish its test"
        )
    trains = read_records(train_csv, TRAIN_NEEDS)
    if not trains:
        raise ValueError(f"{train_csv} has no rows; the run did not finish")
    last_train = trains[-1]
    validation = [
        [_number(evals_csv, evals, r, "episodes", int), _number(evals_csv, evals, r, "win_rate")]
        for r in evals
        if r["split"] == "validation"
    ]
    test: dict[str, dict[str, float]] = {}
    for r in tests:
        key = r["weights"] + ("" if r["contexts"] == "main" else f" {r['contexts']}")
        test[key] = {
            k: _number(evals_csv, evals, r, k)
            for k in ("win_rate", "draw_rate", "loss_rate", "mean_return")
        }
        test[key]["episodes"] = _number(evals_csv, evals, r, "eval_episodes", int)
    return {
        "name": name,
        "run_dir": str(run_dir),
        "episodes": _number(evals_csv, evals, tests[0], "episodes", int),
        "env_steps": _number(evals_csv, evals, tests[0], "env_steps", int),
        "updates": _number(train_csv, trains, last_train, "updates", int),
        "train_wall_seconds": _number(train_csv, trains, last_train, "wall_seconds"),
        "test": test,
        "validation": validation,
        "config": {k: config[k] for k in CONFIG_KEYS if k in config},
    }


def main(argv: list[str] | None = None) -> int:
    """Summarise the runs, print their table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="NAME=RUN_DIR, one per run")
    add_out(parser)
    parser.add_argument("--note", default="", help="what the runs are, for the reader")
    args = parser.parse_args(argv)
    pairs = [run.split("=", 1) for run in args.runs]
    if any(len(pair) != 2 or not all(pair) for pair in pairs):
        parser.error("each run is NAME=RUN_DIR")
    names = [name for name, _ in pairs]
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        parser.error(f"each run needs its own NAME; given twice: {twice}")
    problem = out_problem(args.out, args.force)
    if problem is not None:
        parser.error(problem)
    try:
        runs = [summarize(name, Path(d)) for name, d in pairs]
    except (OSError, ValueError) as exc:  # no such run, unreadable or unfinished (named)
        parser.error(str(exc))
    rows = [
        {"run": r["name"], "episodes": r["episodes"], "env steps": r["env_steps"],
         "final": r["test"]["latest"]["win_rate"],
         "best-validated": r["test"].get("best", {}).get("win_rate", "")}
        for r in runs
    ]  # fmt: skip
    print(table(rows, ["run", "episodes", "env steps", "final", "best-validated"]))
    payload = {
        "what": args.note,
        "commit": commit(),
        "machine": machine(),
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "runs": runs,
    }
    print(f"wrote {write_out(args.out, payload, indent=1)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
