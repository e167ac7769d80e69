"""How a trained checkpoint's games end: decided early or at the time limit, and by how much.

    python -m bench.outcomes RUN_DIR/checkpoint.pt [--level easy] [--episodes 80] [--seed S]

Plays the checkpoint greedily against the bot (in process, episode ``k`` reset with seed
``S + k``, the same starts the trainer's test split uses when ``S = 10⁹ + 10⁷``) and
records for every episode its winner, its length in decisions, each team's HP and bullets
left, the damage each team dealt per bullet fired, the decision after which each team had
no bullets left, and the kills. Prints the episodes that were not won, a summary table,
and writes ``bench/out/outcomes.json``. Why: the win rate alone cannot tell a policy that
loses by being destroyed from one that loses close races on HP at the time limit, which
call for different fixes (see docs/results.md).
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from typing import Any

import torch

from bench.common import machine, table, write_json
from neuronsmae.server.arena import Arena
from neuronsmae.server.sim.field import START_BULLETS
from neuronsmae.trainers.config import TrainConfig
from neuronsmae.trainers.evaluate import GreedyPolicy, MatchPolicy
from neuronsmae.trainers.train import TEST_SEED_OFFSET

TEST_SEED = TrainConfig().eval_seed + TEST_SEED_OFFSET
"""First seed of the trainer's test split, so the games are those its final figures count."""


def play(policy: GreedyPolicy, arena: Arena, level: str, seed: int) -> dict[str, Any]:
    """One greedy episode; the outcome as plain values (blue = the checkpoint's team).

    Besides the end state it keeps what decides a race on HP when bullets run out: the
    damage each team dealt per bullet it fired (1 is a front plate at under 3 m, 3 a rear
    plate) and the decision after which each team had no bullets left (``None``: never).
    """
    obs = arena.reset(contexts={"level": level}, seed=seed)
    policy.reset()
    done, decisions, info = False, 0, {}
    dry: dict[str, int | None] = {"blue": None, "red": None}
    fired = {"blue": 0, "red": 0}
    before = {"blue": 2 * START_BULLETS, "red": 2 * START_BULLETS}
    while not done:
        obs, _, done, info = arena.step(policy.act(obs, arena.get_avail_actions()))
        decisions += 1
        for team, left in (("blue", info["bullets"][:2]), ("red", info["bullets"][2:])):
            fired[team] += max(before[team] - sum(left), 0)  # counted, so refills cannot skew it
            before[team] = sum(left)
            if dry[team] is None and before[team] == 0:
                dry[team] = decisions
    hp, bullets, dealt = info["hp"], info["bullets"], info["damage_dealt"]
    return {
        "seed": seed,
        "winner": info["winner"],
        "decisions": decisions,
        "blue_hp": sum(hp[:2]),
        "red_hp": sum(hp[2:]),
        "blue_bullets": sum(bullets[:2]),
        "red_bullets": sum(bullets[2:]),
        "blue_damage_per_bullet": _per_bullet(sum(dealt[:2]), fired["blue"]),
        "red_damage_per_bullet": _per_bullet(sum(dealt[2:]), fired["red"]),
        "blue_dry_at": dry["blue"],
        "red_dry_at": dry["red"],
        "kills": info["kills"],
    }


def _per_bullet(damage: float, fired: int) -> float:
    return damage / fired if fired else float("nan")


def _median(values: list[float | None]) -> float:
    """Median of the values that exist (NaN and ``None`` left out); NaN if none do."""
    kept = [v for v in values if v is not None and not math.isnan(v)]
    return statistics.median(kept) if kept else float("nan")


def summarize(games: list[dict[str, Any]], limit: int) -> list[dict[str, Any]]:
    """One row per outcome (won / not won): count, at the limit, out of bullets, HP margin,
    then medians of each team's damage per bullet and of the decision each team ran dry."""
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
                **{
                    f"{team}_{what}": _median([g[f"{team}_{what}"] for g in group])
                    for what in ("damage_per_bullet", "dry_at")
                    for team in ("blue", "red")
                },
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
                f"{g['red_bullets']}, damage per bullet {g['blue_damage_per_bullet']:.2f} v "
                f"{g['red_damage_per_bullet']:.2f}, kills {g['kills']}"
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
