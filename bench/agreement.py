"""Which held-out games several checkpoints win, alone and as an ensemble.

    python -m bench.agreement CKPT [CKPT ...] [--level easy] [--episodes 200] [--seed S]
        [--ensemble-of CKPT ...]

Plays every checkpoint greedily against the bot on the same starts (episode ``k`` reset
with seed ``S + k``; by default the trainer's test split, so the games are those its final
figures count), then the :class:`EnsemblePolicy` of the checkpoints (all of them, or those
given to ``--ensemble-of``), which acts greedily on their mean Q-values. Reports each win
rate, how many games are won by exactly 0, 1, ..., n of the checkpoints, the share won by at
least one (what choosing the right checkpoint per game would reach: an upper bound for
these policies, not a policy) and by all. Prints a table and writes
``bench/out/agreement.json`` with every game's winner per policy.

Why: a plateau in the win rate can mean two things. If every run loses the same games,
those starts are lost by the task as posed (no policy of this kind wins them); if each run
loses different ones, the runs are noisy estimates of a better policy, and averaging them
(or their weights, ``eval_ema``) should recover part of the difference.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from bench.common import machine, table, write_json
from bench.outcomes import TEST_SEED, play
from neuronsmae.server.arena import Arena
from neuronsmae.trainers.evaluate import EnsemblePolicy, GreedyPolicy, MatchPolicy


def wins(policy: Any, level: str, seeds: Sequence[int]) -> list[bool]:
    """Whether ``policy`` (``reset``/``act``) wins each of the games started from ``seeds``."""
    arena = Arena(seed=0, **MatchPolicy.options)  # the task the trainers' agents are built for
    try:
        return [play(policy, arena, level, seed)["winner"] == "blue" for seed in seeds]
    finally:
        arena.close()


def agreement(won: Sequence[Sequence[bool]]) -> dict[str, Any]:
    """Across policies (rows) and games (columns): how many games ``k`` policies win, for
    ``k = 0..n``, and the shares won by at least one and by all."""
    grid = np.asarray(won, dtype=bool)
    per_game = grid.sum(axis=0)
    return {
        "games_won_by_k": np.bincount(per_game, minlength=grid.shape[0] + 1).tolist(),
        "won_by_any": float(grid.any(axis=0).mean()),
        "won_by_all": float(grid.all(axis=0).mean()),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint files or run directories")
    parser.add_argument("--level", default="easy", choices=["easy", "middle", "hard"])
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=TEST_SEED)
    parser.add_argument("--ensemble-of", nargs="*", default=None, help="default: all")
    args = parser.parse_args()
    torch.set_num_threads(1)
    seeds = [args.seed + k for k in range(args.episodes)]
    rows, won = [], []
    for path in args.checkpoints:
        won.append(wins(GreedyPolicy(path), args.level, seeds))
        rows.append({"policy": path, "win_rate": float(np.mean(won[-1]))})
        print(f"{path}: {rows[-1]['win_rate']:.3f}", flush=True)
    members = args.ensemble_of if args.ensemble_of is not None else args.checkpoints
    ensemble = wins(EnsemblePolicy(members), args.level, seeds)
    rows.append({"policy": f"ensemble of {len(members)}", "win_rate": float(np.mean(ensemble))})
    summary = agreement(won)
    print(table(rows, ["policy", "win_rate"]))
    print(
        f"games won by exactly k of the {len(won)} checkpoints (k = 0, 1, ...): "
        f"{summary['games_won_by_k']}; by at least one {summary['won_by_any']:.3f}, "
        f"by all {summary['won_by_all']:.3f}"
    )
    report = {
        "level": args.level,
        "seed": args.seed,
        "episodes": args.episodes,
        "policies": rows,
        "ensemble_members": members,
        **summary,
        "won": {path: w for path, w in zip(args.checkpoints, won, strict=True)},
        "ensemble_won": ensemble,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('agreement', report)}")


if __name__ == "__main__":
    main()
