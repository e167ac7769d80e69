"""``neuronsmae-league``: a round-robin league over policies and bots, rated with OpenSkill.

    neuronsmae-league runs/selfplay [more runs or checkpoints ...] --bots easy,middle,hard \\
        --games 20 --out runs/selfplay/league

Players: each checkpoint file given, each run directory's snapshots (``snapshots/*.pt``,
oldest first) and final ``checkpoint.pt``, and each bot of ``--bots``. Every pair meets in
``--games`` episodes, half with each side as blue, both halves on seeds ``seed, seed + 1,
...`` (so each start is played with both colours); matches are played by
``neuronsmae-match``'s engine, in process or on servers (``--port``/``--servers``).

Ratings: OpenSkill's Plackett-Luce model (Weng and Lin, "A Bayesian Approximation Method
for Online Ranking", JMLR 2011; the ``openskill`` package), updated game by game in a fixed
order (pairs in player order, games in episode order), a draw as a tie. Each player's μ and
σ are reported with the interval μ ± 2σ; the table is sorted by μ. The win-rate matrix
holds each row player's score against each column player (wins plus half the draws, over
their games) and is drawn as a picture. ``--out DIR`` writes ``league.json`` (players,
ratings, matrix, every pair's results), ``league.md`` (the table) and ``league.png`` (the
matrix); a folder that already holds one of them is refused, never overwritten.

Before the first game every policy is loaded once and the ``--out`` folder is checked, so
an unreadable snapshot or an unwritable folder is reported at once, not after the games.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.levels import LEVEL_ARGS
from neuronsmae.trainers.outputs import check_folder
from neuronsmae.trainers.play.match import Side, add_arena_arguments, play

SNAPSHOTS = "snapshots"
CHECKPOINT = "checkpoint.pt"
RESULTS = ("league.json", "league.md", "league.png")
"""The files ``--out`` receives."""


@dataclass(frozen=True)
class Player:
    """One entrant: what ``neuronsmae-match`` takes as a side, and a short name."""

    spec: str
    """A bot level or a checkpoint path."""
    name: str
    """As shown in the table and the matrix."""


def expand(entries: Sequence[str], bots: Sequence[str]) -> list[Player]:
    """The players: checkpoint files as given, run directories as their snapshots then
    their final checkpoint, then the bots."""
    players: list[Player] = []
    for entry in entries:
        path = Path(entry)
        if path.is_file():
            players.append(Player(str(path), _short(path)))
        elif path.is_dir():
            files = sorted((path / SNAPSHOTS).glob("*.pt"))
            files += [path / CHECKPOINT] if (path / CHECKPOINT).is_file() else []
            files = files or sorted(path.glob("*.pt"))
            if not files:
                raise InvalidOptionError(f"{path} holds no checkpoints (*.pt, {SNAPSHOTS}/)")
            players += [Player(str(f), _short(f)) for f in files]
        else:
            raise InvalidOptionError(f"{entry!r} is neither a checkpoint file nor a directory")
    for bot in bots:
        if bot not in LEVEL_ARGS:
            raise InvalidOptionError(f"--bots: {bot!r} is not a bot level; valid: {LEVEL_ARGS}")
        players.append(Player(bot, f"bot:{bot}"))
    specs = [p.spec if p.spec in LEVEL_ARGS else str(Path(p.spec).resolve()) for p in players]
    twice = sorted({p.spec for p, s in zip(players, specs, strict=True) if specs.count(s) > 1})
    if twice:
        raise InvalidOptionError(f"a league plays each player once; named twice: {twice}")
    names = [p.name for p in players]
    if len(set(names)) != len(names):  # same file names in several runs: keep the folder
        players = [Player(p.spec, p.spec if p.spec not in LEVEL_ARGS else p.name)
                   for p in players]  # fmt: skip
    if len(players) < 2:
        raise InvalidOptionError(f"a league needs at least two players, got {names}")
    return players


def _short(path: Path) -> str:
    run = path.parent.parent if path.parent.name == SNAPSHOTS else path.parent
    return f"{run.name}/{path.stem}"


def check_players(players: Sequence[Player]) -> None:
    """Load every policy once, so an unreadable one is named before the first game rather
    than after the pairs before it have been played."""
    for player in players:
        if player.spec not in LEVEL_ARGS:
            Side.of(player.spec, f"player {player.name}")


def check_out(out: Path) -> None:
    """Refuse an ``--out`` folder that holds a league's results already, or that cannot be
    created or written into (before any game)."""
    if out.exists() and not out.is_dir():
        raise InvalidOptionError(f"--out {out} exists and is not a directory")
    taken = [name for name in RESULTS if (out / name).exists()]
    if taken:
        raise InvalidOptionError(
            f"--out {out} already holds a league's results ({', '.join(taken)}), which this "
            "league would overwrite; choose another --out or remove them"
        )
    check_folder(out, "--out")


def run_league(players: Sequence[Player], games: int, seed: int, **where: Any) -> dict[str, Any]:
    """Every pair's games, the OpenSkill ratings and the score matrix (module docstring).
    ``where``: :func:`~neuronsmae.trainers.play.match.play`'s ``arenas``, ``port``,
    ``servers`` and ``options``. Every player is loaded before the first game."""
    from openskill.models import PlackettLuce

    if games < 1:
        raise InvalidOptionError(f"--games must be at least 1, got {games}")
    check_players(players)
    model = PlackettLuce()
    ratings = [model.rating(name=p.name) for p in players]
    n = len(players)
    score, played = np.zeros((n, n)), np.zeros((n, n))
    pairs = []
    for a, b in itertools.combinations(range(n), 2):
        for blue, red, count in ((a, b, -(-games // 2)), (b, a, games // 2)):
            if count == 0:
                continue
            result = play(players[blue].spec, players[red].spec, count, seed, **where)
            pairs.append({k: v for k, v in result.items() if k != "winners"}
                         | {"blue": players[blue].name, "red": players[red].name})  # fmt: skip
            for winner in result["winners"]:
                ranks = {"blue": [0, 1], "red": [1, 0]}.get(winner, [0, 0])
                ratings[blue], ratings[red] = (
                    team[0] for team in model.rate([[ratings[blue]], [ratings[red]]], ranks=ranks)
                )
                got = {"blue": 1.0, "red": 0.0}.get(winner, 0.5)
                score[blue, red] += got
                score[red, blue] += 1.0 - got
                played[blue, red] += 1
                played[red, blue] += 1
    matrix = np.divide(score, played, out=np.full((n, n), np.nan), where=played > 0)
    table = [
        {"player": p.name, "spec": p.spec, "mu": r.mu, "sigma": r.sigma,
         "lo": r.mu - 2 * r.sigma, "hi": r.mu + 2 * r.sigma, "ordinal": r.ordinal()}
        for p, r in zip(players, ratings, strict=True)
    ]  # fmt: skip
    return {
        "players": [p.name for p in players],
        "ratings": sorted(table, key=lambda row: -row["mu"]),
        "matrix": [[None if np.isnan(v) else round(float(v), 4) for v in row] for row in matrix],
        "games": games,
        "seed": seed,
        "pairs": pairs,
        "model": "openskill PlackettLuce, one update per game, interval mu ± 2 sigma",
    }


def table_text(league: dict[str, Any]) -> str:
    """The ratings as a Markdown table."""
    lines = ["| rank | player | μ | σ | μ ± 2σ |", "| --- | --- | --- | --- | --- |"]
    for i, row in enumerate(league["ratings"], start=1):
        lines.append(
            f"| {i} | {row['player']} | {row['mu']:.2f} | {row['sigma']:.2f} | "
            f"{row['lo']:.2f} – {row['hi']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def draw_matrix(league: dict[str, Any], out: Path) -> Path:
    """The score matrix as a PNG heat map, each cell labelled."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = league["players"]
    m = np.array([[np.nan if v is None else v for v in row] for row in league["matrix"]])
    size = 1.0 + 0.55 * len(names)
    fig, ax = plt.subplots(figsize=(size + 2.5, size + 1.0))
    image = ax.imshow(m, vmin=0.0, vmax=1.0, cmap="RdYlGn")
    ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(names)), names, fontsize=8)
    for (i, j), v in np.ndenumerate(m):
        if not np.isnan(v):
            ax.text(j, i, f"{v:.2f}", ha="center", va="center", fontsize=7)
    ax.set_xlabel("opponent")
    ax.set_ylabel("player")
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    ax.set_title(
        f"score of each player against each opponent\n(wins + draws / 2 over "
        f"{league['games']} games, both colours)",
        fontsize=9,
    )
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="neuronsmae-league", description=__doc__.split("\n")[0])
    p.add_argument("entries", nargs="*", metavar="DIR_OR_CHECKPOINT")
    p.add_argument("--bots", default="easy,middle,hard",
                   help="comma list of bot levels; '' for none (easy,middle,hard)")  # fmt: skip
    p.add_argument("--games", type=int, default=20, help="episodes per pair, half each colour")
    add_arena_arguments(p)
    p.add_argument("--out", type=Path,
                   help="write league.json, league.md and league.png into this folder, which "
                   "must not hold them already")  # fmt: skip
    p.add_argument("--json", action="store_true", help="print the league as JSON")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.arenas < 1 or (args.servers is not None and args.servers < 1):
        parser.error(f"--arenas and --servers must be at least 1, got {args.arenas} and "
                     f"{args.servers}")  # fmt: skip
    if args.games < 1:
        parser.error(f"--games must be at least 1, got {args.games}")
    if args.out is not None:
        try:
            check_out(args.out)
        except InvalidOptionError as exc:
            parser.error(str(exc))
    bots = [b.strip() for b in args.bots.split(",") if b.strip()]
    try:
        players = expand(args.entries, bots)
        league = run_league(
            players, args.games, args.seed, arenas=args.arenas, port=args.port,
            servers=args.servers, options=dict(args.option),
        )  # fmt: skip
    except (NeuronsMAEError, OSError) as exc:
        print(f"neuronsmae-league: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(league) if args.json else table_text(league), end="")  # kept if a write fails
    if args.out is not None:
        try:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / "league.json").write_text(json.dumps(league, indent=2))
            (args.out / "league.md").write_text(table_text(league))
            draw_matrix(league, args.out / "league.png")
        except OSError as exc:
            print(f"neuronsmae-league: --out {args.out}: {exc}", file=sys.stderr)
            return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
