"""``neuronsmae-train``: train IQL, VDN or QMIX blue agents against the rule-based red bot.

Layers, later ones winning: the defaults of :class:`TrainConfig`, ``--preset paper`` (the
paper's hyper-parameters), ``--config FILE`` (TOML or JSON), ``--set key=value``
(repeatable; ``learner.lr=1e-3``, or ``lr=1e-3`` since the name is unique), then the
dedicated flags (``--alg``, ``--level``, ``--workers``, ...). With ``--resume`` the run
directory's saved ``config.json`` replaces the defaults, so a resumed run keeps its settings
unless told otherwise (e.g. a larger ``--episodes``). Unknown or ambiguous keys are errors
that list the valid ones; ``--help-config`` lists every key by group.

Example: ``neuronsmae-train --alg vdn --level easy`` trains locally with the defaults and
prints the final greedy win rate on held-out seeds.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from neuronsmae.trainers.core.mixers import ALGORITHMS
from neuronsmae.trainers.run.config import (
    ENV_KINDS,
    GROUPS,
    KEYS,
    LEVELS,
    PRESETS,
    ConfigError,
    TrainConfig,
    check_resumable,
    field_docs,
    make_config,
    parse_overrides,
    preset,
    read_config_file,
)
from neuronsmae.trainers.run.records import check_new_run_dir, make_run_dir


def build_parser() -> argparse.ArgumentParser:
    """The command line; every flag defaults to None so only given flags override."""
    summary = __doc__.split("\n")[0].replace("``", "")
    p = argparse.ArgumentParser(prog="neuronsmae-train", description=summary)
    p.add_argument("--alg", choices=sorted(ALGORITHMS), help="learning algorithm (mixer)")
    p.add_argument("--level", choices=LEVELS, help="red bot (with --opponent: the evaluations')")
    p.add_argument(
        "--opponent",
        metavar="POOL",
        help="train against a pool: comma list of bot levels, checkpoints and 'self'",
    )
    p.add_argument("--workers", type=int, help="rollout workers (default: cores - 1, at least 2)")
    p.add_argument("--episodes", type=int, help="training episodes in total")
    p.add_argument("--out", help="run directory (default runs/<alg>_<level>_s<seed>)")
    p.add_argument("--seed", type=int, help="run seed")
    p.add_argument("--env", choices=ENV_KINDS, help="in-process arenas or remote servers")
    p.add_argument("--address", help="join this Ray cluster instead of starting one")
    p.add_argument(
        "--sync",
        action="store_const",
        const=True,
        help="paper's loop: one episode per worker per iteration",
    )
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--preset", choices=sorted(PRESETS), help="named settings (paper)")
    p.add_argument("--config", help="TOML or JSON file of config keys")
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one config key (repeatable)",
    )
    p.add_argument("--help-config", action="store_true", help="list every config key")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


FLAG_KEYS = {
    "alg": "alg",
    "level": "level",
    "opponent": "opponent",
    "workers": "workers",
    "episodes": "episodes",
    "out": "out",
    "seed": "seed",
    "env": "env",
    "address": "cluster.address",
    "sync": "sync",
}
"""Flags that map one-to-one onto config keys: flag name → key."""


def config_from_args(args: argparse.Namespace) -> TrainConfig:
    """Build the config from the layers described in the module docstring."""
    flags: dict[str, Any] = {
        key: getattr(args, flag)
        for flag, key in FLAG_KEYS.items()
        if getattr(args, flag) is not None
    }
    if args.quiet:
        flags["progress"] = False
    layers = [preset(args.preset)] if args.preset else []
    layers += [read_config_file(args.config)] if args.config else []
    layers += [parse_overrides(args.set), flags]
    base = None
    if args.resume:
        probe = make_config(*layers)
        saved = probe.run_dir / "config.json"
        if not saved.is_file():
            raise ConfigError(f"--resume: no {saved}; pass the run's --out")
        if not (probe.run_dir / "checkpoint.pt").is_file():
            raise ConfigError(
                f"--resume: {probe.run_dir} holds no checkpoint.pt (the run stopped before its "
                "first one); start it afresh instead: remove the directory, or another --out"
            )
        base = saved_config(saved)
    cfg = make_config(*layers, base=base)
    if base is not None:
        check_resumable(base, cfg)
    if cfg.run_dir.exists() and not cfg.run_dir.is_dir():
        raise ConfigError(f"out {str(cfg.run_dir)!r} exists and is not a directory")
    if not args.resume:
        check_new_run_dir(cfg.run_dir)
    return cfg


def saved_config(path: Path) -> TrainConfig:
    """The config a run saved in its ``config.json``, for ``--resume``."""
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ConfigError(f"--resume: {path} is not the JSON a run writes ({err})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"--resume: {path} must hold a table of config keys")
    try:
        return make_config(data)
    except ConfigError as err:
        raise ConfigError(f"--resume: {path}: {err}") from None


def print_config_help() -> None:
    """Every config key by group, with its default and docstring."""
    defaults = TrainConfig().to_dict()
    docs = field_docs()
    for group in ("", *GROUPS):
        keys = [k for k in KEYS if k.rpartition(".")[0] == group]
        title = f"[{group}]  {group}.<key>, or the bare key" if group else "[top level]"
        print(f"{title}\n")
        for key in keys:
            value = defaults[group][key.rpartition(".")[2]] if group else defaults[key]
            print(f"{key} = {value!r}\n    {docs[key]}\n")


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``neuronsmae-train``; returns the process exit code."""
    args = build_parser().parse_args(argv)
    if args.help_config:
        print_config_help()
        return 0
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        cfg = config_from_args(args)
        make_run_dir(cfg.run_dir)
    except (ConfigError, OSError) as err:
        print(f"neuronsmae-train: {err}", file=sys.stderr)
        return 2
    from neuronsmae.trainers.core.checkpoint import CheckpointError
    from neuronsmae.trainers.run.interrupt import TrainingInterrupted
    from neuronsmae.trainers.run.sampler import PlacementError
    from neuronsmae.trainers.run.train import train  # heavy imports (Ray, torch) after parsing

    try:
        result = train(cfg, resume=args.resume)
    except (ConfigError, CheckpointError, PlacementError) as err:  # what only the run finds
        print(f"neuronsmae-train: {err}", file=sys.stderr)
        return 2
    except TrainingInterrupted as stop:
        print(f"neuronsmae-train: {stop}", file=sys.stderr)
        return 130
    final, counters = result["final"], result["counters"]
    print(
        f"{cfg.alg}{f' (trained against {cfg.opponent})' if cfg.opponent else ''} vs "
        f"{cfg.level} bot: greedy win rate {final['win_rate']:.2f} over "
        f"{final['eval_episodes']} held-out episodes (draws {final['draw_rate']:.2f}, "
        f"return {final['mean_return']:.1f}) after {counters['episodes']} episodes, "
        f"{counters['env_steps']} env steps, {counters['wall_seconds']:.0f} s; "
        f"checkpoint {Path(result['run_dir']) / 'checkpoint.pt'}"
    )
    best = result.get("best")
    if best is not None:
        print(
            f"best validated weights (chosen at {best['chosen_at_episodes']} episodes, "
            f"validation win rate {best['validation']['win_rate']:.2f}): greedy win rate "
            f"{best['win_rate']:.2f} on the same test episodes; "
            f"{Path(result['run_dir']) / 'best.pt'}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
