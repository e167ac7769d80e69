"""The paper's table, measured: IQL, VDN, QMIX × easy, middle, hard × seeds, resumable.

    python -m bench.paper_table [--learner paper|defaults|defaults_released|paper_dr]
                                [--algs ...] [--levels easy middle hard 0 1] [--seeds 1 2 3]
                                [--runs runs/table] [--out docs/data/paper_table.json]
                                [--report | --test-at KEY=VALUE;...]

``--learner paper`` (the default) trains every cell with ``--preset paper``, the authors'
released training code (trainers/run/presets.py ``PRESETS``): 30,000 episodes, then the final
weights tested on 200 held-out episodes at coef 1.5 with the released win rule, the
referee's win/draw/loss beside it, and at coef 1.0 as a second column. ``--learner
defaults`` trains with this project's own learner under a 30-minute budget (VDN by
default: ``--algs vdn``) at its default contexts, tested at coef 1.0 and 1.5;
``--learner defaults_released`` is the like-for-like row: the same learner trained at the
released contexts (μ 0.5, coef 0.5) and tested as released (coef 1.5, the released win
rule; coef 1.0 beside it). ``--learner paper_dr`` is ``--preset paper`` trained with the
released ``--dr_coef`` (coef drawn per episode from {0.5, 0.7, 1, 1.4, 1.7, 2}; VDN by
default, as run_dr.sh), tested as ``paper``. Levels are the paper's bots and the released
build's levels ``0`` and ``1``.

Cells run one at a time, seed-major (every cell's first seed before any second seed), so a
partial table covers every cell early. Each run has its own directory under ``--runs``; a
run stopped half-way is resumed from its checkpoint (a time-budgeted run is started afresh,
its old folder renamed ``<run>.stale-<time>``: its budget is per session), Ctrl-C stops the
run in progress with a checkpoint, and a run already in ``--out`` is skipped, so the same
command continues the table after any interruption. After each run one record is written
to ``--out`` (atomically): alg, level, learner, seed, episodes, env steps, gradient updates,
transitions sampled into them, iterations, wall minutes, the training contexts, each
test's contexts and figures (both win rules, draws, losses, return), the headline win
rule, the run directory, the commit and the machine; the run's logs (config, train.csv,
eval.csv) are copied to ``<out>_runs/`` (the record's ``logs``, relative to the folder of
``--out``) so that ``neuronsmae-plot docs/data/paper_table_runs/paper/*_easy_*`` draws the
learning curves whatever machine ran them. ``--env`` picks in-process arenas (the default
here: the same episodes as served arenas, without a server process competing for the 2
cores) or served ones. ``--set KEY=VALUE`` overrides any config key but those that name
the cell (``alg``, ``level``, ``seed``, ``out``; tests use it for tiny runs). Prints the
table so far at the end (``--report``: only that, as Markdown: bench/paper_report.py).
``--test-at "coef=0.5"`` tests the recorded runs' final weights again with their test
contexts so updated (``level=...`` among them plays that bot instead of the run's), on the
same starts (their checkpoints must still be in ``--runs``), stores the results and the
contexts in the records and stops; the report then adds a table of them.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.common import Distinct, at_least, commit, non_negative
from bench.paper_report import ALGS, LEARNERS, LEVELS, RELEASED, TEST_FIELDS, report
from neuronsmae.protocol.contexts import check_contexts
from neuronsmae.trainers.core.checkpoint import CHECKPOINT_NAME, load_checkpoint
from neuronsmae.trainers.play.evaluate import evaluate_checkpoint
from neuronsmae.trainers.run.config import (
    ConfigError,
    TrainConfig,
    make_config,
    parse_overrides,
    preset,
)
from neuronsmae.trainers.run.contexts import ContextSpec
from neuronsmae.trainers.run.interrupt import TrainingInterrupted
from neuronsmae.trainers.run.records import read_records
from neuronsmae.trainers.run.train import TEST_SEED_OFFSET, train

LEARNER_LAYERS: dict[str, dict[str, Any]] = {
    "defaults": {"eval.extra_test_contexts": "coef=1.5"},
    "defaults_released": {
        "contexts": "Friction_coeff=0.5;coef=0.5",
        "eval.eval_contexts": "Friction_coeff=0.5;coef=1.5",
        "eval.extra_test_contexts": "coef=1.0",
        "eval.win_rule": "released",
    },
}
"""The project's learner's layers over its defaults, by ``--learner`` (the paper preset is
a layer of its own): tested at coef 1.5 beside its own coef 1.0, or trained and tested at
the released contexts with the released win rule (the like-for-like row)."""


DR_COEF_CONTEXTS = "Friction_coeff=0.5;coef=0.5,0.7,1,1.4,1.7,2"
"""``--learner paper_dr``'s training contexts: the released ``--dr_coef`` (run_dr.sh), coef
drawn per episode from the released list (common/arguments.py), μ 0.5 as in the preset."""


def cell_config(
    args: argparse.Namespace, alg: str, level: str, seed: int, run_dir: Path
) -> TrainConfig:
    """The configuration of one run of the table."""
    layers: list[dict[str, Any]] = []
    if args.learner == "paper":
        layers.append(preset("paper"))
    elif args.learner == "paper_dr":
        layers += [preset("paper"), {"contexts": DR_COEF_CONTEXTS}]
    else:
        layers.append({"max_minutes": args.minutes, **LEARNER_LAYERS[args.learner]})
    layers.append(
        {
            "alg": alg,
            "level": level,
            "seed": seed,
            "workers": args.workers,
            "env": args.env,
            "out": str(run_dir),
            "progress": sys.stderr.isatty(),
            "torch_threads": args.torch_threads,
        }
    )
    overrides = parse_overrides(args.set)
    fixed = sorted(set(overrides) & set(CELL_KEYS))
    if fixed:
        raise ConfigError(
            f"--set {', '.join(fixed)}: the table sets these per cell; choose cells with "
            "--algs, --levels, --seeds, and their folder with --runs"
        )
    layers.append(overrides)
    return make_config(*layers)


CELL_KEYS = ("alg", "level", "seed", "out")
"""Config keys that make a run the cell it is recorded as: never changed by ``--set``."""


class TableFileError(ValueError):
    """``--out`` holds something other than a table this script wrote."""


def load(path: Path) -> dict[str, Any]:
    """The recorded table at ``path`` (an empty one where there is no file yet)."""
    if not path.exists():
        return {"records": []}
    try:
        table = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise TableFileError(f"--out {path} is not a table this script wrote: {exc}") from None
    if not isinstance(table, dict) or not isinstance(table.get("records"), list):
        raise TableFileError(f"--out {path} is JSON but holds no list of 'records'")
    return table


def save(path: Path, table: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(table, indent=1))
    tmp.replace(path)


def _figures(row: dict[str, Any]) -> dict[str, Any]:
    """What a record keeps of one evaluation row: :data:`TEST_FIELDS` and the episodes."""
    return {k: row[k] for k in TEST_FIELDS} | {"episodes": row["eval_episodes"]}


def record(
    args: argparse.Namespace, alg: str, level: str, seed: int, result: dict[str, Any],
    cfg: TrainConfig,
) -> dict[str, Any]:  # fmt: skip
    """One run's line of the table."""
    counters = result["counters"]
    tests = {"main": result["final"], **result.get("extra_tests", {})}
    level_bot = {"level": int(level) if level in RELEASED else level}
    return {
        "alg": alg,
        "level": level,
        "learner": args.learner,
        "preset": "paper" if args.learner in ("paper", "paper_dr") else None,
        "seed": seed,
        "episodes": counters["episodes"],
        "env_steps": counters["env_steps"],
        "updates": counters["updates"],
        "samples": counters.get("samples", 0),
        "iterations": counters.get("rounds", 0),
        "wall_minutes": round(counters["wall_seconds"] / 60, 2),
        "contexts": cfg.contexts,
        "win_rule": cfg.eval.win_rule,
        "test_contexts": {
            name: level_bot | spec.value() for name, spec in cfg.eval.context_specs().items()
        },
        "test": {name: _figures(row) for name, row in tests.items()},
        "run_dir": result["run_dir"],
        "commit": commit(),
        "machine": {
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "platform": platform.platform(),
        },
        "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


LOGS = ("config.json", "train.csv", "eval.csv")
"""What is kept of each run beside the table: enough for ``neuronsmae-plot`` to draw its
learning curve in a later session, on another machine (the checkpoints are not kept)."""


def keep_logs(run_dir: Path, out: Path, learner: str) -> Path:
    """Copy the run's logs to ``<out>_runs/<learner>/<run>/`` and return that directory."""
    dest = out.with_name(f"{out.stem}_runs") / learner / run_dir.name
    dest.mkdir(parents=True, exist_ok=True)
    for name in LOGS:
        shutil.copy2(run_dir / name, dest / name)
    return dest


def set_aside(run_dir: Path) -> Path:
    """Rename a run folder the table cannot resume to ``<name>.stale-<time>`` (never
    deleted: it may hold a person's files) and return the new path."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    aside = run_dir.with_name(f"{run_dir.name}.stale-{stamp}")
    n = 1
    while aside.exists():
        n += 1
        aside = run_dir.with_name(f"{run_dir.name}.stale-{stamp}-{n}")
    run_dir.rename(aside)
    return aside


def finished_result(run_dir: Path, saved: dict[str, Any]) -> dict[str, Any]:
    """What ``train`` returned for a finished run, read back from its checkpoint and the
    final tests in its ``eval.csv`` (the final weights' rows at its last episode count)."""
    episodes = saved["counters"]["episodes"]
    needs = ("episodes", "split", "weights", "contexts", "eval_episodes", *TEST_FIELDS)
    rows = [
        r for r in read_records(run_dir / "eval.csv", needs)
        if (r["split"], r["weights"]) == ("test", "latest")
        and int(float(r["episodes"])) == episodes
    ]  # fmt: skip
    tests = {
        r["contexts"]: {k: float(r[k]) for k in TEST_FIELDS}
        | {"eval_episodes": int(float(r["eval_episodes"]))}
        for r in rows
    }
    if "main" not in tests:
        raise ValueError(
            f"{run_dir}: its checkpoint is finished at {episodes} episodes but eval.csv holds "
            "no final test at that count; move the folder aside to train the cell again"
        )
    main_test = tests.pop("main")
    return {"final": main_test, "extra_tests": tests, "counters": saved["counters"],
            "run_dir": str(run_dir)}  # fmt: skip


def run_cell(args: argparse.Namespace, alg: str, level: str, seed: int) -> dict[str, Any]:
    run_dir = args.runs / args.learner / f"{alg}_{level}_s{seed}"
    cfg = cell_config(args, alg, level, seed, run_dir)
    saved = load_checkpoint(run_dir) if (run_dir / CHECKPOINT_NAME).is_file() else None
    if (
        saved is not None
        and saved.get("finished")
        and (cfg.max_minutes > 0 or saved["counters"]["episodes"] >= cfg.episodes)
    ):
        # Trained and tested, but the table stopped before recording it: record it as is.
        print(f"recording {run_dir}, finished before it was recorded", flush=True)
        result = finished_result(run_dir, saved)
    else:
        if run_dir.exists() and (cfg.max_minutes > 0 or saved is None):
            # A time budget is per session: a resumed run would train past it; a run stopped
            # before its first checkpoint cannot be continued. Either starts afresh.
            print(f"{run_dir} cannot be resumed: moved to {set_aside(run_dir)}", flush=True)
            saved = None
        if saved is not None:
            print(f"resuming {run_dir} at {saved['counters']['episodes']} episodes", flush=True)
        else:
            print(f"starting {run_dir}", flush=True)
        result = train(cfg, resume=saved is not None)
    line = record(args, alg, level, seed, result, cfg)
    # Relative to the table's own folder, so the record stays true wherever the table and
    # its ``_runs`` folder are copied together (a run on another machine, into docs/data).
    line["logs"] = (
        keep_logs(run_dir, args.out, args.learner).relative_to(args.out.parent).as_posix()
    )
    return line


def test_at(args: argparse.Namespace, extra: str) -> int:
    """Test every recorded run's final weights again with its test contexts updated by
    ``extra`` (e.g. ``coef=0.5``, the paper preset's training context), on the same test
    starts and as many episodes; stored in the record's ``test`` under ``extra``.

    Needs each run's checkpoint (the record's ``run_dir``, else ``--runs``), and refuses
    one whose episode count is not the record's: that would not be the final weights. Where
    ``extra`` changes nothing of the run's own test (``level=easy`` for a run trained and
    tested against easy), that test is the main one, and its figures are copied without a
    checkpoint. Returns how many records were added to.
    """
    more = ContextSpec.parse(extra)
    added = 0
    for rec in load(args.out)["records"]:
        if rec["learner"] != args.learner or extra in rec["test"]:
            continue
        tested = _retest(args, rec, more)
        if tested is None:
            continue
        figures, at = tested
        table = load(args.out)  # the table's own runner may have added records meanwhile
        key = (rec["alg"], rec["level"], rec["seed"], rec["learner"])
        for line in table["records"]:
            if (line["alg"], line["level"], line["seed"], line["learner"]) == key:
                line["test"][extra] = figures
                line.setdefault("test_contexts", {})[extra] = at
        save(args.out, table)
        added += 1
        print(f"{rec['alg']}/{rec['level']}/s{rec['seed']} at {at}: {figures['win_rate']:.3f}")
    return added


def _retest(
    args: argparse.Namespace, rec: dict[str, Any], more: ContextSpec
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """One record's figures and contexts under ``more``; ``None`` without its checkpoint."""
    own = rec.get("test_contexts", {}).get("main")
    if own is not None and all(own.get(k) == v for k, v in more.value().items()):
        return dict(rec["test"]["main"]), dict(own)  # the same test: the main one
    run_dir = Path(rec["run_dir"])
    if not (run_dir / CHECKPOINT_NAME).is_file():
        run_dir = args.runs / rec["learner"] / f"{rec['alg']}_{rec['level']}_s{rec['seed']}"
    if not (run_dir / CHECKPOINT_NAME).is_file():
        print(f"no checkpoint for {rec['alg']}/{rec['level']}/s{rec['seed']}: skipped")
        return None
    saved = load_checkpoint(run_dir)
    if saved["counters"]["episodes"] != rec["episodes"]:
        raise ValueError(
            f"{run_dir / CHECKPOINT_NAME} holds {saved['counters']['episodes']} episodes, "
            f"the record {rec['episodes']}: not the recorded final weights"
        )
    spec = saved["config"]["eval"]
    contexts = ContextSpec.parse(spec["eval_contexts"]).updated(more).value()
    level = contexts.pop("level", rec["level"])  # a bot of --test-at's replaces the run's
    row = evaluate_checkpoint(
        run_dir / CHECKPOINT_NAME, level, rec["test"]["main"]["episodes"],
        spec["eval_seed"] + TEST_SEED_OFFSET, contexts=contexts,
    )  # fmt: skip
    return _figures(row), {"level": level, **contexts}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--learner", choices=LEARNERS, default="paper")
    p.add_argument("--algs", nargs="+", action=Distinct, choices=ALGS, default=None)
    p.add_argument(
        "--levels", nargs="+", action=Distinct, choices=(*LEVELS, *RELEASED), default=list(LEVELS)
    )
    p.add_argument("--seeds", nargs="+", action=Distinct, type=at_least(0), default=[1, 2, 3])
    p.add_argument("--workers", type=at_least(0), default=2, help="rollout workers (0: auto)")
    p.add_argument("--env", choices=("inprocess", "remote"), default="inprocess")
    p.add_argument(
        "--torch-threads",
        type=at_least(1),
        default=min(2, os.cpu_count() or 1),
        help="the learner's threads (default: 2, or 1 on one core; the synchronous loop "
        "learns while the workers wait)",
    )
    p.add_argument(
        "--minutes", type=non_negative, default=30.0, help="defaults: budget per run (0: none)"
    )
    p.add_argument("--runs", type=Path, default=Path("runs/table"))
    p.add_argument("--out", type=Path, default=Path("docs/data/paper_table.json"))
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="config override"
    )
    p.add_argument("--report", action="store_true", help="print the table of --out and stop")
    p.add_argument(
        "--test-at",
        type=fixed_contexts,
        metavar="KEY=VALUE;...",
        help="test the recorded runs' final weights again with these contexts over their "
        "test contexts (e.g. coef=0.5, the training context), store the results and stop",
    )
    args = p.parse_args(argv)
    try:
        load(args.out)  # refused before any run, never overwritten
        cell_config(args, "vdn", args.levels[0], args.seeds[0], args.runs)  # the --set keys
    except (TableFileError, ConfigError) as exc:
        p.error(str(exc))
    if args.report and args.test_at is not None:
        p.error("--report and --test-at are alternatives: give one")
    if args.test_at is not None:
        print(f"{test_at(args, args.test_at)} record(s) tested at {args.test_at}")
        return 0
    if args.report:
        table = load(args.out)
        print(report(table, _seed_count(table, args.seeds)))
        return 0
    algs = args.algs or (list(ALGS) if args.learner == "paper" else ["vdn"])  # run_dr.sh: VDN
    table = load(args.out)
    for seed in args.seeds:
        for level in args.levels:
            for alg in algs:
                if level in RELEASED and alg != "vdn":
                    continue  # the released levels are VDN's rows (run_dr.sh)
                key = (alg, level, seed, args.learner)
                done = {(r["alg"], r["level"], r["seed"], r["learner"]) for r in table["records"]}
                if key in done:
                    continue
                try:
                    line = run_cell(args, alg, level, seed)
                except TrainingInterrupted as exc:  # checkpoint saved: the same command resumes
                    print(f"paper_table: {exc.signal_name}: {alg}/{level}/s{seed} stopped at "
                          f"{exc.episodes} episodes with its checkpoint; run the same command "
                          "to resume it", file=sys.stderr)  # fmt: skip
                    return 130
                table = load(args.out)  # another process may have added records meanwhile
                table["records"].append(line)
                save(args.out, table)
                print(f"recorded {alg}/{level}/s{seed}: {line['test']}", flush=True)
    print(report(table, _seed_count(table, args.seeds)))
    return 0


def fixed_contexts(text: str) -> str:
    """``--test-at``'s value, checked: contexts with one fixed value each, at least one,
    each a key and value the arena takes (the protocol's context table)."""
    try:
        values = ContextSpec.parse(text).value()
        if not values:
            raise ValueError("give at least one KEY=VALUE (e.g. coef=0.5)")
        check_contexts(values)
    except ValueError as exc:  # ContextSpecError or InvalidContextError, naming the entry
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def _seed_count(table: dict[str, Any], seeds: Sequence[int]) -> int:
    """Seeds per cell the report expects: those asked for and those already recorded (a
    run of ``--seeds 1`` alone still reports the table's three)."""
    return len(set(seeds) | {r["seed"] for r in table["records"]})


if __name__ == "__main__":
    sys.exit(main())
