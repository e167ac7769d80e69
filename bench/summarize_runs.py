"""Summarise finished training runs into one JSON for docs/data, and print their table.

``python -m bench.summarize_runs NAME=RUN_DIR... --out docs/data/NAME.json [--note TEXT]``

Each ``RUN_DIR`` is a finished ``neuronsmae-train`` run directory. The summary takes from
its ``config.json`` the settings that name the run, from ``eval.csv`` the greedy
validation curve and the test figures (200 held-out episodes, final and best-validated
weights, one row per test context set), and from ``train.csv`` the learner's counters, so a
document quotes a run that is gone from disk. The commit the runs were made from is
``NEURONSMAE_COMMIT`` when set (as for runs made from a ``git archive`` snapshot), else
this checkout's ``git rev-parse HEAD``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bench.common import machine, table

CONFIG_KEYS = ("alg", "level", "seed", "workers", "env", "envs_per_worker", "max_minutes",
               "opponent", "preset", "contexts", "arena", "selfplay")  # fmt: skip
"""The configuration fields a summary keeps: those that tell the runs of a table apart."""


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def _head() -> str:
    done = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True)
    return done.stdout.strip()


def summarize(name: str, run_dir: Path) -> dict[str, Any]:
    """The summary of one finished run: its settings, counters, test figures and curve."""
    try:
        config = json.loads((run_dir / "config.json").read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{run_dir}/config.json is not a run's configuration: {exc}") from None
    evals = _rows(run_dir / "eval.csv")
    tests = [r for r in evals if r["split"] == "test"]
    if not tests:
        raise ValueError(f"{run_dir}: eval.csv has no test rows; the run did not finish")
    last_train = _rows(run_dir / "train.csv")[-1]
    test: dict[str, dict[str, float]] = {}
    for r in tests:
        key = r["weights"] + ("" if r["contexts"] == "main" else f" {r['contexts']}")
        test[key] = {k: float(r[k]) for k in ("win_rate", "draw_rate", "loss_rate", "mean_return")}
        test[key]["episodes"] = int(r["eval_episodes"])
    return {
        "name": name,
        "run_dir": str(run_dir),
        "episodes": int(tests[0]["episodes"]),
        "env_steps": int(tests[0]["env_steps"]),
        "updates": int(last_train["updates"]),
        "train_wall_seconds": float(last_train["wall_seconds"]),
        "test": test,
        "validation": [
            [int(r["episodes"]), float(r["win_rate"])] for r in evals if r["split"] == "validation"
        ],
        "config": {k: config[k] for k in CONFIG_KEYS if k in config},
    }


def main(argv: list[str] | None = None) -> int:
    """Summarise the runs, print their table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", help="NAME=RUN_DIR, one per run")
    parser.add_argument("--out", type=Path, required=True, help="JSON file to write")
    parser.add_argument("--note", default="", help="what the runs are, for the reader")
    args = parser.parse_args(argv)
    pairs = [run.split("=", 1) for run in args.runs]
    if any(len(pair) != 2 or not all(pair) for pair in pairs):
        parser.error("each run is NAME=RUN_DIR")
    names = [name for name, _ in pairs]
    if len(set(names)) != len(names):
        twice = sorted({n for n in names if names.count(n) > 1})
        parser.error(f"each run needs its own NAME; given twice: {twice}")
    if args.out.suffix != ".json" or args.out.is_dir():
        parser.error(f"--out must name a .json file, got {str(args.out)!r}")
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
        "commit": os.environ.get("NEURONSMAE_COMMIT") or _head(),
        "machine": machine(),
        "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "runs": runs,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(payload, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
