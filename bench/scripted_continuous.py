"""Scripted continuous-action teams against a bot: what the continuous task asks of a learner.

    python -m bench.scripted_continuous [--level easy] [--episodes 200]
                                        [--teams still random spin aim aim_close] [--out FILE]

Each team plays blue on the trainers' held-out test episodes (episode ``i`` reset with seed
``1,010,000,000 + i``, the starts of docs/results.md's final tests) in one in-process arena
with ``action_space="continuous"``, against the bot ``--level``; win / draw / loss by the
referee, with Wilson 95 % intervals. The teams, each robot deciding from its own
observation (columns found through ``EnvInfo``, never by number):

* ``still``: no motion, the nearest living enemy as target;
* ``random``: uniform commands within the bounds and a random target (seeded);
* ``spin``: turning in place at the limit;
* ``aim``: no translation; the chassis turns toward the nearest living enemy, ω = heading
  error / decision time, clamped to the bound. Abstract and discrete actions do this for
  the learner (docs/reference.md, Actions); with continuous actions the learner must find it,
  and a robot only fires at a plate within ±0.52 rad of its heading;
* ``aim_close``: ``aim``, driving forward or back to hold 2.5 m from that enemy (the
  candidate points' radius, the best hit factor's range).

Prints a Markdown table and writes bench/out/scripted_continuous.json (or ``--out``).
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench.benchmarl_baselines import TEST_SEED
from bench.common import (
    Distinct,
    add_out,
    at_least,
    commit,
    machine,
    out_problem,
    table,
    write_json,
    write_out,
)
from neuronsmae.client import make_arena
from neuronsmae.protocol import EnvInfo
from neuronsmae.protocol.env_info import FIELD_HALF
from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg
from neuronsmae.trainers.play.match import wilson

RANGE = 2.5
"""Distance ``aim_close`` holds to its target (m): the candidate points' radius."""

Team = Callable[[np.ndarray, EnvInfo, np.random.Generator], list[float]]
"""One robot's observation → its continuous action (vx, vy, ω, target)."""


def _pose(obs: np.ndarray, info: EnvInfo, robot: int) -> tuple[float, float, float]:
    """Robot ``robot``'s (x m, y m, yaw rad) from the scaled observation (self is robot 0)."""
    cx, cy, cyaw = info.obs.pose(robot)
    (hx, hy) = FIELD_HALF
    return obs[cx] * hx + hx, obs[cy] * hy + hy, obs[cyaw] * math.pi


def _nearest(obs: np.ndarray, info: EnvInfo) -> tuple[int, float, float]:
    """The nearest living enemy (the nearest of all when none is seen living), its distance
    and the heading error toward it (wrapped to [−π, π))."""
    x, y, yaw = _pose(obs, info, 0)
    seen = []
    for j in range(info.n_enemies):
        robot = info.obs.enemy(j)
        ex, ey, _ = _pose(obs, info, robot)
        err = (math.atan2(ey - y, ex - x) - yaw + math.pi) % (2 * math.pi) - math.pi
        dead = obs[info.obs.hp_of(robot)] <= -1.0  # HP scaled to [−1, 1]: −1 is 0 HP
        seen.append((dead, math.hypot(ex - x, ey - y), j, err))
    _, d, j, err = min(seen)
    return j, float(d), float(err)


def _turn(err: float, info: EnvInfo) -> float:
    """ω that closes the heading error ``err`` within one decision, clamped to the bound."""
    limit = info.motion_bounds[1][2]
    return float(np.clip(err / (0.02 * info.decision_steps), -limit, limit))


def still(obs: np.ndarray, info: EnvInfo, rng: np.random.Generator) -> list[float]:
    return [0.0, 0.0, 0.0, float(_nearest(obs, info)[0])]


def random(obs: np.ndarray, info: EnvInfo, rng: np.random.Generator) -> list[float]:
    low, high = info.motion_bounds
    return [*map(float, rng.uniform(low, high)), float(rng.integers(info.n_enemies))]


def spin(obs: np.ndarray, info: EnvInfo, rng: np.random.Generator) -> list[float]:
    return [0.0, 0.0, float(info.motion_bounds[1][2]), float(_nearest(obs, info)[0])]


def aim(obs: np.ndarray, info: EnvInfo, rng: np.random.Generator) -> list[float]:
    j, _, err = _nearest(obs, info)
    return [0.0, 0.0, _turn(err, info), float(j)]


def aim_close(obs: np.ndarray, info: EnvInfo, rng: np.random.Generator) -> list[float]:
    j, d, err = _nearest(obs, info)
    limit = info.motion_bounds[1][0]
    forward = float(np.clip(d - RANGE, -limit, limit)) * math.cos(err)
    return [forward, 0.0, _turn(err, info), float(j)]


TEAMS: dict[str, Team] = {
    "still": still, "random": random, "spin": spin, "aim": aim, "aim_close": aim_close,
}  # fmt: skip
"""The scripted teams by name (module docstring)."""


def play(team: str, level: str, episodes: int, seed: int = 0) -> dict[str, Any]:
    """``team`` as blue against the bot ``level`` on ``episodes`` held-out test episodes."""
    rng = np.random.default_rng(seed)
    outcomes: Counter[str] = Counter()
    env = make_arena("inprocess", TEST_SEED, action_space="continuous")
    try:
        info = EnvInfo(**env.get_env_info())
        for i in range(episodes):
            obs = env.reset({"level": level_from_arg(level)}, seed=TEST_SEED + i)
            done = False
            while not done:
                actions = [TEAMS[team](np.asarray(o), info, rng) for o in obs]
                obs, _, done, step = env.step(actions)
            outcomes[step["winner"]] += 1
    finally:
        env.close()
    row: dict[str, Any] = {"team": team, "level": level, "episodes": episodes}
    for name, key in (("win", "blue"), ("draw", "draw"), ("loss", "red")):
        row[f"{name}_rate"] = outcomes[key] / episodes
        row[f"{name}_ci95"] = list(wilson(outcomes[key], episodes))
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--level", default="easy", choices=LEVEL_ARGS, help="the bot blue plays (easy)")
    p.add_argument("--episodes", type=at_least(1), default=200)
    p.add_argument("--teams", nargs="+", choices=list(TEAMS), default=list(TEAMS),
                   action=Distinct)  # fmt: skip
    add_out(p, "scripted_continuous")
    args = p.parse_args(argv)
    if problem := out_problem(args.out, args.force):
        p.error(problem)
    rows = [play(team, args.level, args.episodes) for team in args.teams]
    for r in rows:
        r["win_ci95_text"] = f"{r['win_ci95'][0]:.3f}–{r['win_ci95'][1]:.3f}"
    print(table(rows, ["team", "level", "episodes", "win_rate", "win_ci95_text", "draw_rate",
                       "loss_rate"]))  # fmt: skip
    payload = {"rows": rows, "first_seed": TEST_SEED, "command": "python -m "
               "bench.scripted_continuous " + " ".join(sys.argv[1:] if argv is None else argv),
               "commit": commit(), "machine": machine()}  # fmt: skip
    path = write_out(args.out, payload) if args.out else write_json("scripted_continuous", payload)
    print(f"wrote {Path(path)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
