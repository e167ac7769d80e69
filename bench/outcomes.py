"""How a trained checkpoint's games end: decided early or at the time limit, and by how much.

    python -m bench.outcomes RUN_DIR/checkpoint.pt [--level easy] [--episodes 80] [--seed S]

Plays the checkpoint greedily against the bot (in process, episode ``k`` reset with seed
``S + k``, the same starts the trainer's test split uses when ``S = 10⁹ + 10⁷``) and
records for every episode its winner, its length in decisions, each team's HP and bullets
left and the kills. Prints the episodes that were not won, a summary table, and writes
``bench/out/outcomes.json``. Why: the win rate alone cannot tell a policy that loses
by being destroyed from one that loses close races on HP at the time limit, which call for
different fixes (see docs/results.md).
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import torch

from bench.common import machine, table, write_json
from neuronsmae.server.arena import Arena
from neuronsmae.trainers.config import TrainConfig
from neuronsmae.trainers.evaluate import GreedyPolicy, MatchPolicy
from neuronsmae.trainers.train import TEST_SEED_OFFSET

TEST_SEED = TrainConfig().eval_seed + TEST_SEED_OFFSET
"""First seed of the trainer's test split, so the games are those its final figures count."""


def play(policy: GreedyPolicy, arena: Arena, level: str, seed: int) -> dict[str, Any]:
    """One greedy episode; the outcome as plain values (blue = the checkpoint's team)."""
    obs = arena.reset(contexts={"level": level}, seed=seed)
    policy.reset()
    done, decisions, info = False, 0, {}
    while not done:
        obs, _, done, info = arena.step(policy.act(obs, arena.get_avail_actions()))
        decisions += 1
    hp, bullets = info["hp"], info["bullets"]
    return {
        "seed": seed,
        "winner": info["winner"],
        "decisions": decisions,
        "blue_hp": sum(hp[:2]),
        "red_hp": sum(hp[2:]),
        "blue_bullets": sum(bullets[:2]),
        "red_bullets": sum(bullets[2:]),
        "kills": info["kills"],
    }


def summarize(games: list[dict[str, Any]], limit: int) -> list[dict[str, Any]]:
    """One row per outcome (won / not won): count, at the limit, out of bullets, HP margin."""
    rows = []
    for name, group in (
        ("won", [g for g in games if g["winner"] == "blue"]),
        ("not won", [g for g in games if g["winner"] != "blue"]),
    ):
        margins = [abs(g["blue_hp"] - g["red_hp"]) for g in group]
        rows.append(
            {
                "outcome": name,
                "episodes": len(group),
                "at_time_limit": sum(g["decisions"] == limit for g in group),
                "both_out_of_bullets": sum(
                    g["blue_bullets"] == 0 and g["red_bullets"] == 0 for g in group
                ),
                "median_hp_margin": statistics.median(margins) if margins else float("nan"),
                "min_hp_margin": min(margins) if margins else float("nan"),
            }
        )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", help="checkpoint file or run directory")
    parser.add_argument("--level", default="easy", choices=["easy", "middle", "hard"])
    parser.add_argument("--episodes", type=int, default=80)
    parser.add_argument("--seed", type=int, default=TEST_SEED)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy = GreedyPolicy(args.checkpoint)
    arena = Arena(seed=0, **MatchPolicy.options)  # the task the trainers' agents are built for
    try:
        limit = int(arena.get_env_info()["episode_limit"])
        games = [play(policy, arena, args.level, args.seed + k) for k in range(args.episodes)]
    finally:
        arena.close()
    for g in games:
        if g["winner"] != "blue":
            print(
                f"seed {g['seed']}: {g['winner']} after {g['decisions']} decisions, HP "
                f"{g['blue_hp']:.0f} v {g['red_hp']:.0f}, bullets {g['blue_bullets']} v "
                f"{g['red_bullets']}, kills {g['kills']}"
            )
    rows = summarize(games, limit)
    print(table(rows, list(rows[0])))
    report = {
        "checkpoint": args.checkpoint,
        "level": args.level,
        "seed": args.seed,
        "episode_limit": limit,
        "summary": rows,
        "games": games,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('outcomes', report)}")


if __name__ == "__main__":
    main()
