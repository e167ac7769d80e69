"""``neuronsmae-plot``: learning curves of training runs, with the paper's results to compare.

    neuronsmae-plot RUN_DIR... [--out curves.png] [--source eval|train|both]

Each ``RUN_DIR`` is what ``neuronsmae-train`` wrote (``config.json``, ``train.csv``,
``eval.csv``; see :mod:`neuronsmae.trainers.run.records`), or a directory holding such run
directories. Runs with the same algorithm and bot level form one curve: the mean across
them (seeds) as a line and their min–max spread as a band, win rate and return against
environment steps. The greedy evaluations (``eval.csv``) are the measure the paper reports,
so where the level is known its final win rate against that bot is drawn as a dotted line.

It reads only the files, never a checkpoint, so it plots runs still in progress and runs
copied from another machine alike; matplotlib comes with the ``train`` extra. A run named
twice (directly or inside a folder named too) is refused: it would count twice in the
mean and spread. ``--out`` is replaced if it exists.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, MissingDependencyError, NeuronsMAEError
from neuronsmae.trainers.outputs import check_file
from neuronsmae.trainers.run.records import RecordsError, read_records

PAPER_WIN_RATE: dict[str, dict[str, float]] = {
    "easy": {"iql": 0.75, "vdn": 0.93, "qmix": 0.89},
    "middle": {"iql": 0.48, "vdn": 0.62, "qmix": 0.57},
    "hard": {"iql": 0.23, "vdn": 0.41, "qmix": 0.34},
}
"""The paper's win rates against the bot, 2 v 2, abstract actions (level → algorithm)."""
LABEL_HEIGHT = 0.05
"""Win rate a paper line's label spans on the win-rate axis (7-point text, 3 points off)."""
COLORS = ("tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown")
GRID_POINTS = 200
"""Environment-step grid that runs are interpolated on before averaging."""


class RunDirError(NeuronsMAEError, ValueError):
    """A path is not a run directory, or holds nothing to plot."""


@dataclass
class Run:
    """One run directory's curves (columns of its CSV files as float arrays)."""

    path: Path
    alg: str
    level: str
    seed: Any
    train: dict[str, np.ndarray] = field(default_factory=dict)
    eval: dict[str, np.ndarray] = field(default_factory=dict)


NEEDS = {
    "train.csv": ("episodes", "env_steps", "train_win_rate", "train_return"),
    "eval.csv": ("episodes", "env_steps", "win_rate", "mean_return"),
}
"""The columns each records file must have to be plotted."""


def read_csv(path: Path, needs: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Columns of a records CSV as float arrays (blank cells → NaN); empty if absent or
    without rows yet. A header that lacks a column of ``needs`` is refused by name.

    Of ``eval.csv`` only the periodic (validation) rows form the curve: the final test-seed
    rows repeat the last step with other seeds or other weights.
    """
    if not path.is_file():
        return {}
    try:
        every = read_records(path, needs)
    except RecordsError as exc:
        raise RunDirError(str(exc)) from None
    rows = [r for r in every if r.get("split") in (None, "", "validation")]
    if not rows:
        return {}
    return {key: np.array([_num(r.get(key)) for r in rows]) for key in rows[0]}


def _num(text: str | None) -> float:
    try:
        return float(text) if text not in (None, "") else math.nan
    except ValueError:
        return math.nan


def find_runs(paths: Iterable[str | Path]) -> list[Path]:
    """Run directories named by ``paths``: each one, or the run directories inside it."""
    found: list[Path] = []
    named: dict[Path, tuple[Path, str]] = {}  # resolved run → (as first found, by which arg)
    for arg in paths:
        p = Path(arg)
        if (p / "config.json").is_file():
            runs = [p]
        elif p.is_dir() and (inner := sorted(c.parent for c in p.glob("*/config.json"))):
            runs = inner
        else:
            raise RunDirError(f"{p} is not a run directory (no config.json) and holds none")
        for run in runs:
            key = run.resolve()
            if key in named:
                first, given = named[key]
                raise RunDirError(
                    f"run {first} is named twice (by {given!r} and {str(arg)!r}): it would "
                    "count twice in the mean and spread; name each run once"
                )
            named[key] = (run, str(arg))
            found.append(run)
    return found


def load_run(path: Path) -> Run:
    """Read one run directory."""
    try:
        config = json.loads((path / "config.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: bad JSON or not UTF-8
        raise RunDirError(f"{path}/config.json is unreadable: {exc}") from None
    if not isinstance(config, dict):
        raise RunDirError(
            f"{path}/config.json is not a run's configuration: a JSON "
            f"{type(config).__name__}, not an object"
        )
    return Run(
        path=path,
        alg=str(config.get("alg", "?")),
        level=str(config.get("level", "?")),
        seed=config.get("seed"),
        train=read_csv(path / "train.csv", NEEDS["train.csv"]),
        eval=read_csv(path / "eval.csv", NEEDS["eval.csv"]),
    )


def mean_and_spread(
    curves: Sequence[tuple[np.ndarray, np.ndarray, np.ndarray]], exact: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(env_steps, mean, low, high)`` of several ``(episodes, env_steps, y)`` curves.

    Runs are aligned on the episode count, not on environment steps: evaluations fall due
    every ``eval_every`` episodes in every run, while the steps they land on differ with
    episode lengths. Only the range every run has reached is kept (the curve stops where
    the shortest run stops), so the mean never jumps where a run joins or leaves. With
    ``exact``, the episode counts all runs share are used as they are (evaluations);
    otherwise the curves are interpolated on a grid (training rows).
    """
    clean = []
    for ep, steps, y in curves:
        ok = np.isfinite(ep) & np.isfinite(steps) & np.isfinite(y)
        order = np.argsort(ep[ok], kind="stable")
        if order.size:
            clean.append((ep[ok][order], steps[ok][order], y[ok][order]))
    empty = (np.empty(0),) * 4
    if not clean:
        return empty
    lo = max(float(ep[0]) for ep, _, _ in clean)
    hi = min(float(ep[-1]) for ep, _, _ in clean)
    if lo > hi:
        return empty
    grid = np.linspace(lo, hi, GRID_POINTS) if hi > lo else np.array([lo])
    if exact:
        shared = set.intersection(*(set(ep.tolist()) for ep, _, _ in clean))
        if shared:
            grid = np.array(sorted(shared))
    steps = np.stack([np.interp(grid, ep, st) for ep, st, _ in clean])
    ys = np.stack([np.interp(grid, ep, y) for ep, _, y in clean])
    return steps.mean(axis=0), ys.mean(axis=0), ys.min(axis=0), ys.max(axis=0)


SERIES = {
    "eval": ("eval", "win_rate", "mean_return"),
    "train": ("train", "train_win_rate", "train_return"),
}
"""Source → (attribute of Run, win-rate column, return column)."""


def plot_runs(
    runs: Sequence[Run], out: Path, source: str = "both", title: str = "", by_run: bool = False
) -> Path:
    """Draw win rate and return against environment steps; write a PNG; return its path.

    Runs of the same algorithm and level are averaged, unless ``by_run`` (one curve each:
    for runs that differ in more than their seed)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError as exc:
        raise MissingDependencyError(
            "neuronsmae-plot needs matplotlib: pip install 'neuronsmae[train]'"
        ) from exc
    groups: dict[tuple[str, str], list[Run]] = {}
    for run in runs:
        key = (run.alg, run.level, run.path.name if by_run else "")
        groups.setdefault(key, []).append(run)
    fig = Figure(figsize=(12.5, 4.2), dpi=100)
    FigureCanvasAgg(fig)
    ax_win, ax_ret = fig.subplots(1, 2)
    sources = ("eval", "train") if source == "both" else (source,)
    drew = False
    for color, ((alg, level, run_name), members) in zip(
        COLORS * 8, sorted(groups.items()), strict=False
    ):
        name = run_name or f"{alg.upper()} vs {level} (n={len(members)})"
        for src in sources:
            attr, win_col, ret_col = SERIES[src]
            style = {"eval": dict(lw=2.0, marker="o", ms=3), "train": dict(lw=1.0, alpha=0.6)}[src]
            for ax, col in ((ax_win, win_col), (ax_ret, ret_col)):
                tables = [getattr(r, attr) for r in members]
                curves = [
                    (t["episodes"], t["env_steps"], t[col])
                    for t in tables
                    if {"episodes", "env_steps", col} <= t.keys()
                ]
                x, mean, low, high = mean_and_spread(curves, exact=src == "eval")
                if not x.size:
                    continue
                drew = True
                label = f"{name}, {'greedy eval' if src == 'eval' else 'training'}"
                ax.plot(x, mean, color=color, label=label, **style)
                if len(curves) > 1:
                    ax.fill_between(
                        x, low, high, color=color, alpha=0.15 if src == "eval" else 0.08
                    )
    if not drew:
        raise RunDirError("the runs have no rows in train.csv or eval.csv yet: nothing to plot")
    _paper_lines(ax_win, {(r.alg.lower(), r.level) for r in runs})
    ax_win.set(xlabel="environment steps", ylabel="win rate vs bot", ylim=(-0.02, 1.02))
    ax_ret.set(xlabel="environment steps", ylabel="episode return (blue team)")
    for ax in (ax_win, ax_ret):
        ax.grid(alpha=0.3)
    handles, labels = ax_win.get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=7, loc="center right")
    default = "one curve per run" if by_run else "line: mean over runs, band: min-max"
    fig.suptitle(title or f"Learning curves ({default})", fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.86, 1))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, format="png")
    return out


def _paper_lines(ax: Any, cells: set[tuple[str, str]]) -> None:
    """A dotted line at the paper's win rate of each (algorithm, level) plotted, labelled
    above the line, or below it where a label above would run into the one higher up."""
    refs = sorted(
        ((PAPER_WIN_RATE[level][alg], alg, level) for alg, level in cells
         if alg in PAPER_WIN_RATE.get(level, {})),
        reverse=True,
    )  # fmt: skip
    lowest = math.inf  # the lowest win rate a label placed so far reaches down to
    for paper, alg, level in refs:
        ax.axhline(paper, color="black", ls=":", lw=1.2)
        above = paper + LABEL_HEIGHT <= lowest
        ax.annotate(
            f"paper {alg.upper()} vs {level}: {paper:.2f}",
            (0.01, paper),
            xycoords=("axes fraction", "data"),
            xytext=(0, 3 if above else -9),
            textcoords="offset points",
            fontsize=7,
        )
        lowest = paper if above else paper - LABEL_HEIGHT


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status."""
    p = argparse.ArgumentParser(prog="neuronsmae-plot", description=__doc__.split("\n")[0])
    p.add_argument("runs", nargs="+", help="run directories, or directories of them")
    p.add_argument(
        "--out", type=Path, default=Path("curves.png"), help="PNG to write (replaced if it exists)"
    )
    p.add_argument(
        "--source",
        choices=("eval", "train", "both"),
        default="both",
        help="greedy evaluations, training episodes, or both (both)",
    )
    p.add_argument("--title", default="", help="figure title")
    p.add_argument(
        "--by-run",
        action="store_true",
        help="one curve per run directory instead of the mean per algorithm and level",
    )
    args = p.parse_args(argv)
    if args.out.suffix.lower() != ".png" or args.out.is_dir():
        p.error(f"--out must name a .png file, got {str(args.out)!r}")
    try:
        check_file(args.out, "--out")
    except InvalidOptionError as exc:
        p.error(str(exc))
    try:
        runs = [load_run(path) for path in find_runs(args.runs)]
        out = plot_runs(runs, args.out, args.source, args.title, args.by_run)
    except (NeuronsMAEError, OSError) as exc:
        print(f"neuronsmae-plot: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {out} ({len(runs)} run{'s' if len(runs) != 1 else ''})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
