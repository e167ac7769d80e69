"""Q-learners and policy-gradient learners on one scale: marl-eval JSON, IQM, bootstrap
intervals and the probability of improvement.

    python -m bench.baselines_report [--baselines docs/data/benchmarl_baselines.json]
                                     [--runs docs/data/marl_eval_runs] [--reps 2000]
                                     [--json docs/data/marl_eval.json]
                                     [--summary docs/data/baselines_summary.json]
                                     [--plot docs/img/baselines_iqm.png]

Gathers every run's final test win rate into one marl-eval JSON (InstaDeep's format, the one
BenchMARL's logger writes; ``--json``): BenchMARL runs from the baselines table
(:mod:`bench.benchmarl_baselines`, the same 200 held-out test episodes and referee's rule as
the trainers' final test) and ``neuronsmae-train`` runs from the ``marl_eval.json`` each run
writes (copied into ``--runs``). Then, per algorithm and task, the interquartile mean (IQM)
of its runs with a 95 % bootstrap interval (one row per task: a task with continuous actions
is not pooled with one with abstract actions), and for every pair of
algorithms with tasks in common the probability that a run of one beats a run of the other
on a task (with its interval), as rliable defines them (Agarwal et al., 2021, "Deep RL at
the edge of the statistical precipice"); written out here with NumPy because rliable 1.2
does not run with today's pandas and arch. ``--plot`` draws both panels.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from neuronsmae.trainers.run.marl_eval import ENVIRONMENT, check_format, merge

Scores = dict[str, np.ndarray]
"""Task → the final win rates of an algorithm's runs on it."""


def from_baselines(table: Mapping[str, Any]) -> dict[str, Any]:
    """The baselines table's records as marl-eval JSON (absolute metrics only)."""
    docs = []
    for r in table.get("records", []):
        task = f"{r['task']}_{r['level']}"
        alg = f"{r['algorithm']} ({r.get('framework', 'benchmarl')})"
        run = {"absolute_metrics": {"win_rate": [r["test"]["win_rate"]]}}
        docs.append({ENVIRONMENT: {task: {alg: {f"seed_{r['seed']}": run}}}})
    return merge(docs)


def scores(document: Mapping[str, Any], metric: str = "win_rate") -> dict[str, Scores]:
    """Algorithm → task → the runs' final ``metric`` (the mean of its listed values)."""
    out: dict[str, Scores] = {}
    for tasks in document.values():
        for task, algorithms in tasks.items():
            for alg, runs in algorithms.items():
                values = [float(np.mean(run["absolute_metrics"][metric]))
                          for run in runs.values() if "absolute_metrics" in run]  # fmt: skip
                if values:
                    out.setdefault(alg, {})[task] = np.asarray(values)
    return out


def iqm(per_task: Scores) -> float:
    """The interquartile mean of every run's score over every task."""
    return float(stats.trim_mean(np.concatenate(list(per_task.values())), 0.25))


def improvement(x: Scores, y: Scores) -> float:
    """P(X > Y): on each shared task, the chance a run of ``x`` beats a run of ``y`` (a tie
    counts one half), averaged over the tasks."""
    shared = sorted(set(x) & set(y))
    per_task = []
    for task in shared:
        a, b = x[task][:, None], y[task][None, :]
        per_task.append(float(np.mean((a > b) + 0.5 * (a == b))))
    return float(np.mean(per_task))


def bootstrap(
    statistic: Callable[..., float], samples: tuple[Scores, ...], reps: int, seed: int = 0
) -> tuple[float, float]:
    """The 95 % percentile interval of ``statistic`` over stratified resamples: each task's
    runs are drawn with replacement on their own, for every algorithm's scores."""
    rng = np.random.default_rng(seed)
    values = []
    for _ in range(reps):
        drawn = tuple(
            {t: s[rng.integers(0, len(s), len(s))] for t, s in sample.items()} for sample in samples
        )
        values.append(statistic(*drawn))
    low, high = np.percentile(values, [2.5, 97.5])
    return float(low), float(high)


def summary(by_alg: dict[str, Scores], reps: int) -> dict[str, Any]:
    """IQM with its interval per algorithm and task, and the probability of improvement per
    pair of algorithms over the tasks they share."""
    out: dict[str, Any] = {"iqm": [], "improvement": []}
    for alg, per_task in sorted(by_alg.items()):
        for task, runs in sorted(per_task.items()):
            one = {task: runs}
            low, high = bootstrap(iqm, (one,), reps)
            out["iqm"].append({"learner": alg, "task": task, "iqm": iqm(one),
                               "ci95": [low, high], "runs": len(runs)})  # fmt: skip
    for a, b in itertools.permutations(sorted(by_alg), 2):
        if set(by_alg[a]) & set(by_alg[b]):
            p = improvement(by_alg[a], by_alg[b])
            low, high = bootstrap(improvement, (by_alg[a], by_alg[b]), reps)
            out["improvement"].append({"x": a, "y": b, "p": p, "ci95": [low, high]})
    return out


def plot(result: dict[str, Any], path: Path) -> Path:
    """IQM with intervals (left) and the probability of improvement (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["iqm"]
    pairs = [p for p in result["improvement"] if p["x"] < p["y"]]
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 0.5 * max(len(rows), len(pairs)) + 1.6))
    for i, row in enumerate(rows):
        left.plot(row["ci95"], [i, i], lw=6, alpha=0.5, color="tab:blue")
        left.plot([row["iqm"]], [i], "k|", ms=14, clip_on=False)
    left.set_yticks(range(len(rows)), [f"{r['learner']}\n{r['task']}" for r in rows])
    left.set_xlabel("IQM of the test win rate per task (95 % bootstrap)")
    left.set_xlim(-0.03, 1.03)  # a mark at 0 or 1 stays visible
    for i, pair in enumerate(pairs):
        right.plot(pair["ci95"], [i, i], lw=6, alpha=0.5, color="tab:orange")
        right.plot([pair["p"]], [i], "k|", ms=14, clip_on=False)
    right.axvline(0.5, color="grey", ls=":")
    right.set_yticks(range(len(pairs)), [f"P({p['x']} > {p['y']})" for p in pairs])
    right.set_xlim(-0.03, 1.03)
    right.set_xlabel("probability of improvement")
    left.invert_yaxis()  # rows top to bottom in the table's order
    right.invert_yaxis()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--baselines", type=Path, default=Path("docs/data/benchmarl_baselines.json"))
    p.add_argument("--runs", type=Path, default=Path("docs/data/marl_eval_runs"),
                   help="marl_eval.json files of neuronsmae-train runs")  # fmt: skip
    p.add_argument("--reps", type=int, default=2000)
    p.add_argument("--json", type=Path, default=Path("docs/data/marl_eval.json"))
    p.add_argument("--summary", type=Path, default=Path("docs/data/baselines_summary.json"))
    p.add_argument("--plot", type=Path, default=Path("docs/img/baselines_iqm.png"))
    args = p.parse_args(argv)
    docs = (
        [from_baselines(json.loads(args.baselines.read_text()))] if args.baselines.exists() else []
    )
    docs += [json.loads(f.read_text()) for f in sorted(args.runs.glob("*.json"))]
    document = merge(docs)
    check_format(document)
    result = summary(scores(document), args.reps)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(document, indent=1))
    args.summary.write_text(json.dumps(result, indent=1))
    for row in result["iqm"]:
        print(
            f"{row['learner']} on {row['task']}: IQM {row['iqm']:.3f} "
            f"[{row['ci95'][0]:.3f}, {row['ci95'][1]:.3f}] over {row['runs']} runs"
        )
    if result["iqm"]:
        print(f"wrote {args.json}, {args.summary} and {plot(result, args.plot)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
