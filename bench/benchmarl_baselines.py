"""Policy-gradient (and other) baselines through BenchMARL, tested like the Q-learners.

    python -m bench.benchmarl_baselines --algorithms mappo ippo --tasks coop_abstract
                                        [--seeds 1 2 3] [--minutes 30] [--level easy]
                                        [--runs runs/benchmarl] [--out FILE.json]
                                        [--set KEY=VALUE ...] [--report]

Each cell is one BenchMARL experiment (BenchMARL's own configuration of the algorithm, an
MLP policy and critic, its default experiment settings on the CPU, arenas in process) of a
NeuronsMAE task (:mod:`neuronsmae.client.benchmarl`) against the ``--level`` bot, trained
for ``--minutes`` of wall time (a callback saves the experiment's checkpoint and stops it
once the time is spent), then tested as the Q-learners of docs/results.md are: its policy
(deterministic: BenchMARL's evaluation mode) plays ``neuronsmae-match`` against the bot on
the 200 held-out test episodes the trainers' final test uses (seeds from ``1,010,000,000``,
the trainers' ``eval_seed + TEST_SEED_OFFSET``), win/draw/loss by the referee. One record per
cell goes to ``--out`` (atomically; a recorded cell is skipped); ``--set`` overrides
BenchMARL's experiment settings
(``--set on_policy_collected_frames_per_batch=2000``). ``--report`` prints the table.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import yaml

from bench.common import Distinct, at_least, commit
from neuronsmae.trainers.run.config_groups import TEST_SEED_OFFSET, EvalConfig

ALGORITHMS = ("mappo", "ippo", "qmix", "vdn", "iql", "masac", "isac", "maddpg", "iddpg")
"""BenchMARL's algorithms by their names there (``benchmarl.algorithms.<Name>Config``)."""
TASKS = ("coop_abstract", "coop_discrete", "coop_continuous", "coop_3v3")
TEST_EPISODES = 200
TEST_SEED = EvalConfig().eval_seed + TEST_SEED_OFFSET
"""The first seed of the trainers' final test (the same 200 starts as docs/results.md)."""


def experiment(alg: str, task: str, seed: int, args: argparse.Namespace, folder: Path) -> Any:
    """The BenchMARL experiment of one cell, in ``folder``."""
    import benchmarl.algorithms as algorithms
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    from neuronsmae.client.benchmarl import NeuronsMAETask
    from neuronsmae.client.benchmarl.callbacks import WallClock

    config = ExperimentConfig.get_from_yaml()
    settings = {
        "loggers": ["csv"], "create_json": False, "evaluation": False, "render": False,
        "max_n_frames": 10**12,
        "checkpoint_at_end": True, "save_folder": str(folder),
    }  # fmt: skip
    for key, value in settings.items():
        setattr(config, key, value)
    for key, text in args.set:
        if not hasattr(config, key):
            raise SystemExit(f"--set {key}: BenchMARL's ExperimentConfig has no such field")
        setattr(config, key, yaml.safe_load(text))
    task_obj = NeuronsMAETask[task.upper()].get_from_yaml()
    task_obj.config.update({"env": "inprocess", "level": args.level})
    algorithm = getattr(algorithms, f"{ALGORITHM_NAMES[alg]}Config").get_from_yaml()
    return Experiment(
        task=task_obj, algorithm_config=algorithm, model_config=MlpConfig.get_from_yaml(),
        critic_model_config=MlpConfig.get_from_yaml(), seed=seed, config=config,
        callbacks=[WallClock(args.minutes)],
    )  # fmt: skip


ALGORITHM_NAMES = {name: name.capitalize() for name in ALGORITHMS}
"""Command-line name → BenchMARL's class prefix (``mappo`` → ``MappoConfig``)."""


def run_cell(alg: str, task: str, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """Train one cell for its budget, test its policy, and return its record."""
    from neuronsmae.client.benchmarl.callbacks import BudgetSpent
    from neuronsmae.trainers.play.match import play

    folder = args.runs / f"{alg}_{task}_{args.level}_s{seed}"
    if folder.exists():  # a cell's budget is per session: a stopped one starts afresh
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    exp = experiment(alg, task, seed, args, folder)
    start = time.perf_counter()
    with contextlib.suppress(BudgetSpent):
        exp.run()
    minutes = (time.perf_counter() - start) / 60
    checkpoints = sorted(Path(exp.folder_name, "checkpoints").glob("checkpoint_*.pt"),
                         key=lambda p: int(p.stem.split("_")[1]))  # fmt: skip
    result = play(str(checkpoints[-1]), args.level, TEST_EPISODES, TEST_SEED)
    return {
        "algorithm": alg, "task": task, "level": args.level, "seed": seed,
        "frames": exp.total_frames, "iterations": exp.n_iters_performed,
        "training_minutes": round(minutes, 2), "framework": "benchmarl",
        "test": {"win_rate": result["blue_win_rate"], "draw_rate": result["draw_rate"],
                 "loss_rate": result["red_win_rate"], "episodes": TEST_EPISODES,
                 "first_seed": TEST_SEED},
        "settings": dict(args.set),
        "command": "python -m bench.benchmarl_baselines " + " ".join(sys.argv[1:]),
        "commit": commit(),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }  # fmt: skip


def load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text()) if path.exists() else {"records": []}


def save(path: Path, table: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(table, indent=1))
    tmp.replace(path)


def _setting(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"--set expects KEY=VALUE, got {text!r}")
    return key.strip(), value.strip()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument(
        "--algorithms", nargs="+", action=Distinct, choices=ALGORITHMS, default=["mappo"]
    )
    p.add_argument("--tasks", nargs="+", action=Distinct, choices=TASKS, default=["coop_abstract"])
    p.add_argument("--seeds", nargs="+", action=Distinct, type=at_least(0), default=[1])
    p.add_argument("--level", default="easy")
    p.add_argument("--minutes", type=float, default=30.0)
    p.add_argument("--runs", type=Path, default=Path("runs/benchmarl"))
    p.add_argument("--out", type=Path, default=Path("docs/data/benchmarl_baselines.json"))
    p.add_argument("--set", action="append", type=_setting, default=[], metavar="KEY=VALUE")
    p.add_argument("--report", action="store_true", help="print the table of --out and stop")
    args = p.parse_args(argv)
    if args.report:
        from bench.pages.results import benchmarl_table

        print("\n".join(benchmarl_table(load(args.out)["records"])))
        return 0
    for seed in args.seeds:
        for task in args.tasks:
            for alg in args.algorithms:
                key = (alg, task, args.level, seed)
                table = load(args.out)
                if key in {
                    (r["algorithm"], r["task"], r["level"], r["seed"]) for r in table["records"]
                }:
                    continue
                print(f"training {alg} on {task} against {args.level}, seed {seed}", flush=True)
                line = run_cell(alg, task, seed, args)
                table = load(args.out)
                table["records"].append(line)
                save(args.out, table)
                print(f"recorded {key}: {line['test']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
