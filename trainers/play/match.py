"""``neuronsmae-match``: play two sides against each other and score them.

    neuronsmae-match --blue hard --red easy --episodes 200 --seed 0 [--json]
    neuronsmae-match --blue runs/a/best.pt --red runs/b/snapshots/self_00001000.pt
    neuronsmae-match --blue 1 --red runs/a --port 10000          # on a running server
    neuronsmae-match --blue hard --red runs/a --servers 2 --arenas 8 --record DIR --gif OUT.gif

Each side is a bot level (the released build's ``0`` and ``1``, the paper's ``easy``,
``middle``, ``hard``, or ``random``, ``middle_spread``, ``hard_flank``; docs/contexts.md,
"Bots") or a policy that an installed ``neuronsmae.policies`` loader takes, such as a
trainers' checkpoint file or run directory (:mod:`neuronsmae.protocol.policies`). Bots on
both sides play in ``mode="bots"``; a policy on blue against a bot on red in the
cooperative mode; a policy on red in the competitive mode, a bot on blue then driving blue
through the ``bot_team`` context. Policies act greedily and batched over ``--arenas``
arenas, in process or on servers (``--port``: the servers there, ``--servers N``: N private
ones). Episode ``i`` is reset with seed ``seed + i``, so the same arguments give the same
numbers, in process or served. ``--record DIR`` writes every episode as a replayable
recording (``neuronsmae-replay``); ``--gif OUT`` draws the first episode, re-simulated in
process from its recording (``OUT`` is replaced if it exists; its folder is checked before
the first episode).

This module imports neither torch nor the simulator at import time: a bot match needs
neither the trainers' extra nor, over servers, PyBullet.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.interface import VecArenaAPI, check_series_seed, count_option
from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg, level_value
from neuronsmae.protocol.messages import MAX_ARENAS
from neuronsmae.protocol.policies import TeamPolicy, layout_differences, load_team_policy
from neuronsmae.protocol.recording import (
    Decision,
    Recording,
    decision_hash,
    existing_recordings,
    recording_name,
    write_recording,
)
from neuronsmae.trainers.outputs import check_file, check_folder

Z95 = 1.959963984540054


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a proportion k/n (well behaved near 0 and 1)."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if k == 0 else max(0.0, centre - half)  # exact at the ends (no 1e-17 residue)
    return low, 1.0 if k == n else min(1.0, centre + half)


@dataclass
class Side:
    """One side of a match: a bot level or a policy."""

    name: str
    """As given (``--blue``/``--red``)."""
    level: int | str | None = None
    """The bot's level (None: a policy plays)."""
    policy: TeamPolicy | None = None

    @classmethod
    def of(cls, side: str | int | os.PathLike[str], what: str) -> Side:
        """A bot level (as a command line gives it, or as a number: 0, 1), or a policy
        through the ``neuronsmae.policies`` loaders (text or a path); anything else is an
        ``InvalidOptionError`` naming ``what`` and the valid sides."""
        if isinstance(side, str) and side in LEVEL_ARGS:
            return cls(side, level=level_from_arg(side))
        if not isinstance(side, (str, os.PathLike)):
            level = level_value(side)
            if level is not None:
                return cls(str(level), level=level)
        policy = load_team_policy(side, what, LEVEL_ARGS)
        return cls(str(os.fspath(side)), policy=policy)


@dataclass
class Setup:
    """How a match is played: the arena options, each episode's contexts, the sides."""

    options: dict[str, Any]
    contexts: dict[str, Any]
    blue: Side
    red: Side


MATCH_OPTIONS = ("mode", "blue_level")
"""Arena options a match sets itself from its two sides (refused in ``options``)."""


def arrange(blue: Side, red: Side, options: Mapping[str, Any] | None = None) -> Setup:
    """The mode, arena options and contexts for ``blue`` against ``red`` (module docstring):
    the policies' training options, then ``options`` over them."""
    taken = sorted(set(options or {}) & set(MATCH_OPTIONS))
    if taken:
        raise InvalidOptionError(
            f"options {taken} are the match's own: it sets them from the two sides it plays"
        )
    given: dict[str, Any] = {}
    for side in (red, blue):  # blue's options win where both policies set one
        if side.policy is not None:
            given.update(side.policy.options)
    given.update(options or {})
    contexts: dict[str, Any] = {}
    if blue.policy is None and red.policy is None:
        given.update(mode="bots", blue_level=blue.level)
        contexts["level"] = red.level
    elif red.policy is None:
        given["mode"] = "cooperative"
        contexts["level"] = red.level
    else:
        given["mode"] = "competitive"
        if blue.policy is None:
            given["blue_level"] = blue.level
            contexts["bot_team"] = "blue"
    return Setup(given, contexts, blue, red)


def open_arenas(
    seed: int, num_envs: int, options: Mapping[str, Any], port: Sequence[int] | None,
    servers: int | None,
) -> VecArenaAPI:  # fmt: skip
    """``num_envs`` arenas seeded ``seed, seed + 1, ...``: in process, or on the servers at
    ``port`` (launched there if nothing answers) or ``servers`` private ones."""
    if port is None and servers is None:
        from neuronsmae.client import make_vec_arena

        return make_vec_arena("inprocess", seed, num_envs, **options)
    from neuronsmae.client import VecRM

    target = None if port is None else list(port)
    return VecRM(seed, port=target, num_envs=num_envs, servers=servers or 1, **options)


def _check_sides(setup: Setup, info: Mapping[str, Any]) -> tuple[int, int]:
    """Each policy's layout against the team it drives; the agent columns of blue and red
    (a cooperative arena's agents are blue's, a competitive one's blue's then red's)."""
    n_agents, team = int(info["n_agents"]), int(info["team_size"])
    for side, what in ((setup.blue, "--blue"), (setup.red, "--red")):
        if side.policy is None:
            continue
        view = {**info, "n_agents": team}
        differ = layout_differences(side.policy.env_info, view)
        if differ:
            raise InvalidOptionError(
                f"{what} {side.name!r} was trained on another layout than this arena's "
                f"({'; '.join(differ)}); pass its options with --option KEY=VALUE"
            )
        side.policy.start(int(info.get("num_envs", 1)), team)
    return team, max(n_agents - team, 0)


class _Episodes:
    """Which episode each arena plays, and the recordings being written."""

    def __init__(self, episodes: int, seed: int, contexts: dict[str, Any], keep: bool) -> None:
        self.queue = list(range(episodes))
        self.seed, self.contexts, self.keep = seed, contexts, keep
        self.recordings: dict[int, Recording] = {}

    def next(self) -> int | None:
        return self.queue.pop(0) if self.queue else None

    def begin(self, arena: int, episode: int, state: np.ndarray, setup: Setup, base: int
              ) -> None:  # fmt: skip
        if self.keep:
            self.recordings[arena] = Recording(
                base + arena, dict(setup.options), self.seed + episode, dict(self.contexts),
                decision_hash(state), meta={"blue": setup.blue.name, "red": setup.red.name,
                                            "episode": episode},
            )  # fmt: skip


def _path(value: Any, name: str) -> Path | None:
    """``record``/``gif`` as a Path (None stays None); ``InvalidOptionError`` unless text
    or a path."""
    if value is None or isinstance(value, Path):
        return value
    if isinstance(value, str) or (
        isinstance(value, os.PathLike) and isinstance(os.fspath(value), str)
    ):
        return Path(value)
    raise InvalidOptionError(
        f"{name} must be a path (str or os.PathLike), got {type(value).__name__} {value!r:.60}"
    )


def play(
    blue: str | int | os.PathLike[str],
    red: str | int | os.PathLike[str],
    episodes: int,
    seed: int,
    *,
    arenas: int = 8,
    port: Sequence[int] | None = None,
    servers: int | None = None,
    record: str | os.PathLike[str] | None = None,
    gif: str | os.PathLike[str] | None = None,
    options: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Play ``episodes`` and return the rates with 95% intervals and each episode's
    ``winners`` in episode order (see the module docstring for the sides and where they
    play).

    A side is a level (its command-line text, or the number 0 or 1) or a policy's text or
    path. ``episodes`` (≥ 1), ``arenas`` (in [1, 64]) and ``seed`` (``seed + episodes - 1``
    ≤ 2⁶³ − 1) are Python or NumPy integers; ``record`` and ``gif`` text or paths. Each is
    checked before anything loads, and an error names it."""
    episodes = count_option("episodes", episodes, 1)
    arenas = count_option("arenas", arenas, 1, MAX_ARENAS)
    seed = check_series_seed(seed, episodes)
    record, gif = _path(record, "record"), _path(gif, "gif")
    setup = arrange(Side.of(blue, "--blue"), Side.of(red, "--red"), options)
    if record is not None and record.exists() and not record.is_dir():
        raise InvalidOptionError(f"record: {record} exists and is not a directory")
    found = existing_recordings(record, "episode_") if record is not None else []
    if found:
        raise InvalidOptionError(
            f"record: {record} already holds {len(found)} recording(s) ({found[0].name}, ...), "
            "which this match's would overwrite; record into an empty or new folder"
        )
    if record is not None:
        check_folder(record, "--record")
    if gif is not None:
        check_file(gif, "--gif")
    k = min(arenas, episodes)
    env = open_arenas(seed, k, setup.options, port, servers)
    try:
        winners, first = _play(env, setup, episodes, seed, k, record, gif is not None)
    finally:
        env.close()
    if gif is not None and first is not None:
        from neuronsmae.client.recorder import write_replay_video

        write_replay_video(first, gif)
    result = summarise(setup.blue.name, setup.red.name, Counter(winners), episodes, seed)
    result["winners"] = winners
    return result


def _play(
    env: VecArenaAPI, setup: Setup, episodes: int, seed: int, k: int, record: Path | None,
    draw: bool,
) -> tuple[list[str], Recording | None]:  # fmt: skip
    """The loop: every arena plays episodes in turn (next-step autoreset); each episode's
    winner in episode order, and the first episode's recording (when it is to be drawn)."""
    nb, nr = _check_sides(setup, env.get_env_info())
    plan = _Episodes(episodes, seed, setup.contexts, record is not None or draw)
    current = [plan.next() for _ in range(k)]
    following: list[int | None] = [None] * k
    obs = env.reset(
        [None if e is None else setup.contexts for e in current],
        [None if e is None else seed + e for e in current],
    )
    state = env.get_state()
    starting = [j for j in range(k) if current[j] is not None]
    _begin(plan, setup, starting, [current[j] for j in starting], state, env)
    winners: list[str] = [""] * episodes
    first: Recording | None = None
    while any(e is not None for e in current):
        acting = [j for j in range(k) if current[j] is not None and following[j] is None]
        rows = _actions(setup, obs, env.get_avail_actions(), acting, nb, nr)
        seeds = [None if e is None else seed + e for e in following]
        ctx = [None if e is None else setup.contexts for e in following]
        active = np.array([e is not None for e in current])
        obs, rewards, dones, infos = env.step(rows, seeds=seeds, contexts=ctx, active=active)
        state = env.get_state()
        for j in range(k):
            if current[j] is None:
                continue
            if following[j] is not None:  # reset by this step
                current[j], following[j] = following[j], None
                _begin(plan, setup, [j], [current[j]], state, env)
                continue
            rec = plan.recordings.get(j)
            if rec is not None:
                rec.decisions.append(
                    Decision.after(rows[j], state[j], rewards[j], bool(dones[j]), infos[j])
                )
            if dones[j]:
                winners[current[j]] = str(infos[j]["winner"])
                if rec is not None:
                    first = rec if rec.meta["episode"] == 0 and draw else first
                    if record is not None:
                        name = recording_name("episode_", rec.meta["episode"], rec.seed)
                        write_recording(record / name, rec)
                following[j] = plan.next()
                if following[j] is None:
                    current[j] = None
    return winners, first


def _begin(plan: _Episodes, setup: Setup, arenas: list[int], episodes: list[Any],
           state: np.ndarray, env: VecArenaAPI) -> None:  # fmt: skip
    """Episodes start in ``arenas``: recordings, and the policies forget those arenas."""
    base = int(getattr(env, "seed", 0))
    for j, e in zip(arenas, episodes, strict=True):
        plan.begin(j, e, state[j], setup, base)
    for side in (setup.blue, setup.red):
        if side.policy is not None and arenas:
            side.policy.reset(arenas)


def _actions(setup: Setup, obs: np.ndarray, avail: np.ndarray, acting: list[int], nb: int,
             nr: int) -> np.ndarray:  # fmt: skip
    """Every arena's action row: blue's policy in the first ``nb`` columns, red's in the
    next ``nr`` (zeros where a bot drives; the arena ignores them). With continuous actions
    each agent's entry is ``(vx, vy, omega, target)``."""
    if setup.options.get("action_space") == "continuous":
        rows = np.zeros((obs.shape[0], obs.shape[1], 4), np.float64)
    else:
        rows = np.zeros((obs.shape[0], obs.shape[1]), np.int64)
    if not acting or obs.shape[1] == 0:
        return rows
    idx = np.asarray(acting)
    for side, cols in ((setup.blue, slice(0, nb)), (setup.red, slice(nb, nb + nr))):
        if side.policy is not None and cols.stop > cols.start:
            rows[idx, cols] = side.policy.act(obs[idx, cols], avail[idx, cols], acting)
    return rows


def summarise(blue: str, red: str, outcomes: Counter[str], n: int, seed: int) -> dict[str, Any]:
    """Rates and Wilson intervals from outcome counts."""
    out: dict[str, Any] = {"blue": blue, "red": red, "episodes": n, "seed": seed}
    for key, name in (("blue", "blue_win_rate"), ("red", "red_win_rate"), ("draw", "draw_rate")):
        out[name] = outcomes[key] / n if n else 0.0
        out[name.replace("rate", "ci95")] = list(wilson(outcomes[key], n))
    return out


def parse_option(text: str) -> tuple[str, Any]:
    """``"n_blue=3"`` → ``("n_blue", 3)``: numbers and booleans as such, else the text."""
    key, sep, value = (x.strip() for x in text.partition("="))
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    lowered = value.lower()
    if lowered in ("true", "false"):
        return key, lowered == "true"
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


def add_arena_arguments(p: argparse.ArgumentParser) -> None:
    """The options ``neuronsmae-match`` and ``neuronsmae-league`` share: the first episode
    seed, arenas at once, where to play (servers at ports, or private ones) and the arena
    options."""
    p.add_argument("--seed", type=int, default=0,
                   help="first episode seed, then +1 per episode (0); for trained checkpoints, "
                   "seeds their runs never trained on, e.g. 1010000000")  # fmt: skip
    p.add_argument("--arenas", type=int, default=8, help="arenas played at once (8)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--port", type=int, nargs="+", help="play on the server(s) at these ports")
    where.add_argument("--servers", type=int, help="play on this many private servers")
    p.add_argument(
        "--option", type=parse_option, action="append", default=[], metavar="KEY=VALUE",
        help="an arena option (docs/options.md), e.g. n_blue=3; repeatable",
    )  # fmt: skip


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="neuronsmae-match", description=__doc__.split("\n")[0])
    side = f"a bot level {list(LEVEL_ARGS)}, or a checkpoint file or run directory"
    p.add_argument("--blue", default="hard", help=side)
    p.add_argument("--red", default="easy", help=side)
    p.add_argument("--episodes", type=int, default=200)
    add_arena_arguments(p)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--record", type=Path, metavar="DIR",
        help="write every episode's recording here (see neuronsmae-replay)",
    )  # fmt: skip
    p.add_argument(
        "--gif", type=Path, metavar="OUT",
        help="draw the first episode as a GIF (replaced if it exists)",
    )  # fmt: skip
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.episodes < 1 or args.arenas < 1:
        parser.error("--episodes and --arenas must be at least 1")
    if args.servers is not None and args.servers < 1:
        parser.error(f"--servers must be at least 1, got {args.servers}")
    if args.gif is not None and args.gif.suffix.lower() != ".gif":
        parser.error("--gif must name a .gif file")
    try:
        result = play(
            args.blue, args.red, args.episodes, args.seed, arenas=args.arenas, port=args.port,
            servers=args.servers, record=args.record, gif=args.gif, options=dict(args.option),
        )  # fmt: skip
    except (NeuronsMAEError, OSError) as exc:
        print(f"neuronsmae-match: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"blue={result['blue']} vs red={result['red']}: {args.episodes} episodes, "
        f"seeds {args.seed}..{args.seed + args.episodes - 1}"
    )
    for label, key in (("blue wins", "blue_win"), ("red wins", "red_win"), ("draws", "draw")):
        lo, hi = result[f"{key}_ci95"]
        print(f"  {label:9s} {result[f'{key}_rate']:.3f}  (95% CI {lo:.3f}-{hi:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
