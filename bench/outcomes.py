"""How a trained checkpoint's games end: decided early or at the time limit, and by how much.

    python -m bench.outcomes RUN_DIR/checkpoint.pt [--level easy] [--episodes 80] [--seed S] \
        [--out FILE.json [--force]]

Plays the checkpoint greedily against the bot (in process, episode ``k`` reset with seed
``S + k``, the same starts the trainer's test split uses when ``S = 10⁹ + 10⁷``) and
records for every episode its winner, its length in decisions, each team's HP and bullets
left, the damage each team dealt per bullet fired, the decision after which each team had
no bullets left, the kills, and the agents' own value of the start (their team Q at the
first decision). Prints the episodes that were not won, a summary table, the win rate by
fifth of that value, and writes ``bench/out/outcomes.json`` (replaced by the next run), or
``--out FILE.json`` (an existing one only with ``--force``). Why: the win rate alone cannot
tell a policy that loses by being destroyed from one that loses close races on HP at the
time limit, which call for different fixes (see docs/results.md); nor starts the agents
judge bad from games they expected to win and then lost.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from typing import Any

import numpy as np
import torch

from bench.common import (
    add_out,
    at_least,
    between,
    machine,
    out_problem,
    table,
    write_json,
    write_out,
)
from neuronsmae.protocol.errors import NeuronsMAEError
from neuronsmae.protocol.messages import MAX_SEED
from neuronsmae.protocol.policies import layout_differences
from neuronsmae.server.arena import Arena
from neuronsmae.server.sim.field import START_BULLETS
from neuronsmae.trainers.play.evaluate import GreedyPolicy, MatchPolicy, QPolicy, act_greedily
from neuronsmae.trainers.run.config import TrainConfig
from neuronsmae.trainers.run.train import TEST_SEED_OFFSET

TEST_SEED = TrainConfig().eval.eval_seed + TEST_SEED_OFFSET
"""First seed of the trainer's test split, so the games are those its final figures count."""


def play(policy: QPolicy, arena: Arena, level: str, seed: int) -> dict[str, Any]:
    """One greedy episode; the outcome as plain values (blue = the checkpoint's team).

    Besides the end state it keeps what decides a race on HP when bullets run out: the
    damage each team dealt per bullet it fired (1 is a front plate at under 3 m, 3 a rear
    plate) and the decision after which each team had no bullets left (``None``: never).
    """
    obs = arena.reset(contexts={"level": level}, seed=seed)
    policy.reset()
    done, decisions, info, opening = False, 0, {}, float("nan")
    dry: dict[str, int | None] = {"blue": None, "red": None}
    fired = {"blue": 0, "red": 0}
    before = {"blue": 2 * START_BULLETS, "red": 2 * START_BULLETS}
    while not done:
        actions, value = act_greedily(policy, obs, arena.get_avail_actions())
        opening = value if decisions == 0 else opening
        obs, _, done, info = arena.step(actions)
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
        "opening_value": opening,
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


def by_opening_value(games: list[dict[str, Any]], parts: int = 5) -> list[dict[str, Any]]:
    """Win rate in each fifth (``parts``) of the games, ranked by the agents' own value of
    the start (their team Q at the first decision), lowest first.

    Why: if the games lost are those the agents already value lowest before they act, the
    losses come from starts they judge bad, not from mistakes later in games they expected
    to win.
    """
    ranked = sorted(games, key=lambda g: g["opening_value"])
    rows = []
    for k, group in enumerate(np.array_split(np.arange(len(ranked)), parts)):
        chosen = [ranked[i] for i in group]
        if not chosen:
            continue
        values = [g["opening_value"] for g in chosen]
        rows.append(
            {
                "fifth": k + 1,
                "lowest_value": round(min(values), 2),
                "highest_value": round(max(values), 2),
                "episodes": len(chosen),
                "win_rate": sum(g["winner"] == "blue" for g in chosen) / len(chosen),
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    """Play the games, print the tables and write the JSON report."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checkpoint", help="checkpoint file or run directory")
    parser.add_argument("--level", default="easy", choices=["easy", "middle", "hard"])
    parser.add_argument("--episodes", type=at_least(1), default=80)
    parser.add_argument("--seed", type=between(0, MAX_SEED), default=TEST_SEED,
                        help=f"the first episode's seed, in [0, {MAX_SEED}]")  # fmt: skip
    add_out(parser, "outcomes")
    args = parser.parse_args(argv)
    if args.seed + args.episodes - 1 > MAX_SEED:
        parser.error(f"--seed {args.seed} with --episodes {args.episodes} runs past the "
                     f"largest seed {MAX_SEED} (episode k plays seed + k)")  # fmt: skip
    problem = out_problem(args.out, args.force)
    if problem is not None:
        parser.error(problem)
    torch.set_num_threads(1)
    try:
        policy = GreedyPolicy(args.checkpoint)
    except NeuronsMAEError as exc:  # a missing, unreadable or foreign checkpoint (named)
        parser.error(str(exc))
    arena = Arena(seed=0, **MatchPolicy.options)  # the task the trainers' agents are built for
    try:
        info = arena.get_env_info()
        differ = layout_differences(policy.spec.env_info, info)
        if differ:
            parser.error(
                f"{args.checkpoint} was trained on another layout than this bench's 2 v 2 "
                f"abstract task ({'; '.join(differ)})"
            )
        limit = int(info["episode_limit"])
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
    fifths = by_opening_value(games)
    print("win rate by the agents' own value of the start (team Q at the first decision):")
    print(table(fifths, list(fifths[0])))
    report = {
        "checkpoint": args.checkpoint,
        "level": args.level,
        "seed": args.seed,
        "episode_limit": limit,
        "summary": rows,
        "by_opening_value": fifths,
        "games": games,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    path = write_json("outcomes", report) if args.out is None else write_out(args.out, report)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
