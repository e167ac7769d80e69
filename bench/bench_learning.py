"""Learning benchmark: train one algorithm against one bot level under a wall-clock budget.

Runs ``neuronsmae.trainers`` with the default configuration (plus ``--set`` overrides),
stops after ``--minutes`` of wall time (or ``--episodes``), evaluates the greedy policy on
``--final-eval`` held-out seeds, prints the learning curve as a table, and writes
``bench/out/learning_<alg>_<level>_<stamp>.json`` (``--out DIR``: into DIR; the name
carries the start time, so no report is replaced) with the greedy win rate against env
steps and wall time. The run trains in ``runs/bench_<alg>_<level>_<stamp>`` (``--set
out=DIR``: in DIR, which must not hold a run; the bench always starts a new one). The
overrides, the run folder and ``--out`` are checked before training starts. Run it from
the repository root as a module. The project's target: VDN against the easy bot reaches a
greedy win rate of at least 0.9 within 30 minutes on a 2-core machine::

    python -m bench.bench_learning --alg vdn --level easy --minutes 30 --workers 2
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

from bench.common import at_least, commit, non_negative
from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.trainers.core.mixers import ALGORITHMS
from neuronsmae.trainers.outputs import check_folder
from neuronsmae.trainers.run.config import (
    LEVELS,
    ConfigError,
    TrainConfig,
    make_config,
    parse_overrides,
)
from neuronsmae.trainers.run.interrupt import TrainingInterrupted
from neuronsmae.trainers.run.records import RunExistsError, check_new_run_dir
from neuronsmae.trainers.run.train import train

OUT = Path(__file__).resolve().parent / "out"
"""Where the JSON reports go (ignored by git)."""
TARGET = {"alg": "vdn", "level": "easy", "win_rate": 0.9, "minutes": 30}
"""The project's learning target (docs/results.md)."""


def target_met(alg: str, level: str, minutes: float, final: dict[str, Any]) -> bool | None:
    """Whether this run meets the target: None when it is not the target's setting (another
    algorithm or bot, or no time budget), else whether the final test win rate reached
    the target's within a training budget (``--minutes``) of at most its minutes."""
    if (alg, level) != (TARGET["alg"], TARGET["level"]) or not minutes > 0:
        return None
    return final["win_rate"] >= TARGET["win_rate"] and minutes <= TARGET["minutes"]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Benchmark options; training knobs go through ``--set key=value``."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--alg", choices=sorted(ALGORITHMS), default="vdn")
    p.add_argument("--level", choices=LEVELS, default="easy")
    p.add_argument(
        "--minutes", type=non_negative, default=30.0, help="wall-clock training budget (0: none)"
    )
    p.add_argument("--episodes", type=at_least(1), default=1_000_000, help="episode cap")
    p.add_argument("--workers", type=at_least(0), default=2, help="rollout workers (0: auto)")
    p.add_argument("--seed", type=at_least(0), default=1)
    p.add_argument(
        "--eval-every", type=at_least(0), default=500, help="episodes between evaluations (0: none)"
    )
    p.add_argument("--eval-episodes", type=at_least(1), default=50)
    p.add_argument("--final-eval", type=at_least(1), default=200, help="episodes of the final eval")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    p.add_argument(
        "--out", type=Path, default=OUT, metavar="DIR", help="folder of the JSON report (bench/out)"
    )
    return p.parse_args(argv)


def print_table(evals: list[dict[str, Any]]) -> None:
    """The learning curve: one row per greedy evaluation."""
    print(
        f"{'episodes':>9} {'env steps':>10} {'wall s':>8} {'win':>6} {'draw':>6} "
        f"{'return':>8}  eval"
    )
    for row in evals:
        print(
            f"{row['episodes']:>9} {row['env_steps']:>10} {row['wall_seconds']:>8.0f} "
            f"{row['win_rate']:>6.2f} {row['draw_rate']:>6.2f} {row['mean_return']:>8.2f}  "
            f"{row.get('split', 'validation')}/{row.get('weights', 'latest')}"
        )


def bench_config(args: argparse.Namespace, run_dir: Path) -> TrainConfig:
    """The training configuration of one benchmark run."""
    return make_config(
        {
            "alg": args.alg,
            "level": args.level,
            "seed": args.seed,
            "workers": args.workers,
            "episodes": args.episodes,
            "max_minutes": args.minutes,
            "out": str(run_dir),
            "eval.eval_every": args.eval_every,
            "eval.eval_episodes": args.eval_episodes,
            "eval.final_eval_episodes": args.final_eval,
            "progress": sys.stderr.isatty(),
        },
        parse_overrides(args.set),
    )


def prepare(args: argparse.Namespace, stamp: str) -> tuple[TrainConfig, Path]:
    """The run's configuration and the report's path, checked before any training: the
    ``--set`` overrides, a new and writable run folder, a writable ``--out`` folder. Raises
    :class:`InvalidOptionError` naming the flag."""
    try:
        cfg = bench_config(args, Path("runs") / f"bench_{args.alg}_{args.level}_{stamp}")
    except ConfigError as exc:
        said = str(exc)
        raise InvalidOptionError(said if "--set" in said else f"--set: {said}") from None
    run_dir = Path(cfg.out)
    if not str(cfg.out).strip():
        raise InvalidOptionError("--set out= needs a folder for the run")
    try:
        check_new_run_dir(run_dir)
    except RunExistsError:
        raise InvalidOptionError(
            f"--set out={cfg.out}: that folder already holds a run; this bench always starts "
            "a new run (it has no --resume): give another out, or remove the folder"
        ) from None
    check_folder(run_dir, f"--set out={cfg.out}")
    check_folder(args.out, "--out")
    report = args.out / f"learning_{args.alg}_{args.level}_{stamp}.json"
    if report.exists():
        raise InvalidOptionError(f"--out {args.out} already holds {report.name}")
    return cfg, report


def main(argv: list[str] | None = None) -> int:
    """Run the benchmark and write its JSON report."""
    args = parse_args(argv)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    try:
        cfg, path = prepare(args, stamp)
    except InvalidOptionError as exc:
        print(f"bench.bench_learning: error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    try:
        result = train(cfg)
    except TrainingInterrupted as stop:  # Ctrl-C: the run's checkpoint is saved, no report
        print(f"bench.bench_learning: {stop} (neuronsmae-train); no report written",
              file=sys.stderr)  # fmt: skip
        return 130
    total = time.perf_counter() - start
    final, best = result["final"], result.get("best")
    print_table(result["evals"])
    print(
        f"final greedy win rate {final['win_rate']:.3f} over {final['eval_episodes']} "
        f"held-out episodes; {result['counters']['episodes']} training episodes, "
        f"{result['counters']['env_steps']} env steps, {total:.0f} s in all"
    )
    if best is not None:
        print(
            f"best validated weights (chosen at {best['chosen_at_episodes']} episodes): "
            f"greedy win rate {best['win_rate']:.3f} on the same {best['eval_episodes']} "
            "test episodes"
        )
    met = target_met(args.alg, args.level, args.minutes, final)
    if met is not None:
        print(
            f"target (VDN against easy, greedy win rate ≥ {TARGET['win_rate']} within "
            f"{TARGET['minutes']} minutes): {'met' if met else 'not met'}"
        )
    report = {
        "alg": args.alg,
        "level": args.level,
        "minutes": args.minutes,
        "workers": args.workers,
        "seed": args.seed,
        "config": cfg.to_dict(),
        "final": final,
        "best": best,
        "curve": result["evals"],
        "counters": result["counters"],
        "start_replays": result["start_replays"],
        "total_seconds": total,
        "target": {**TARGET, "met": met},
        "commit": commit(),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
