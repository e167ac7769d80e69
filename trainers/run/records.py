"""Run records: CSV files, TensorBoard scalars and the live progress bar, in one place.

CSV is the durable record (``train.csv`` every logged round, ``eval.csv`` every greedy
evaluation, ``episodes.csv`` every training episode with its contexts; a resumed run
appends), TensorBoard the convenient one, and tqdm shows a person
watching the run what it is doing now: episodes, env steps/s, win rate and loss.

A run has two budgets, its episodes and this session's minutes, and stops at whichever runs
out first; the bar shows progress and the time left against that one and names it
(:func:`budget_status`), so a 30-minute run on a small machine does not show an hour's
ETA toward 30,000 episodes it will never play.
"""

from __future__ import annotations

import csv
import fcntl
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from neuronsmae.protocol.errors import NeuronsMAEError
from neuronsmae.trainers.checks import ConfigError

RUN_FILES = (
    "config.json", "checkpoint.pt", "best.pt", "train.csv", "eval.csv", "episodes.csv",
    "marl_eval.json",
)  # fmt: skip
"""The files a run writes in its directory: their presence means a run is there."""
PERMILLE = 1000
"""The bar's resolution: thousandths of the binding budget."""
TRAIN_COLUMNS = (
    "episodes",
    "env_steps",
    "updates",
    "samples",
    "wall_seconds",
    "epsilon",
    "train_win_rate",
    "train_return",
    "loss",
    "q_taken",
    "grad_norm",
    "lr",
    "env_steps_per_s",
    "restarts",
)
"""Columns of ``train.csv`` (win rate and return over the recent training episodes)."""
EVAL_COLUMNS = (
    "episodes",
    "env_steps",
    "updates",
    "wall_seconds",
    "win_rate",
    "draw_rate",
    "loss_rate",
    "released_win_rate",
    "mean_return",
    "eval_episodes",
    "split",
    "weights",
    "contexts",
)
"""Columns of ``eval.csv`` (greedy play on held-out seeds): ``split`` is ``validation``
(periodic) or ``test`` (final); ``weights`` is ``latest`` or ``best`` (see ``keep_best``);
``contexts`` names the evaluation's fixed contexts (``main``, or an extra test set)."""
EPISODE_COLUMNS = (
    "episode", "seed", "epsilon", "winner", "return", "length", "contexts", "opponent",
)  # fmt: skip
"""Columns of ``episodes.csv``: every stored training episode, with the contexts it was
played with (a JSON map) and red's pool member (``opponent``; empty without a pool), in the
order they were stored."""


@dataclass(frozen=True)
class BudgetStatus:
    """How far the run is along the budget that will end it."""

    binding: str
    """``episodes`` or ``time``: the budget that runs out first at the current pace."""
    fraction: float
    """Share of that budget spent, in [0, 1]."""
    eta_seconds: float
    """Seconds until it runs out (``inf`` while the pace is unknown and time is unlimited)."""


def budget_status(
    episodes: int, total: int, first: int, elapsed: float, limit: float
) -> BudgetStatus:
    """The binding budget of a session that started at episode ``first`` and has played up
    to ``episodes`` of ``total`` in ``elapsed`` seconds of its ``limit`` (0: no time limit).

    The episode budget ends after the episodes left at this session's pace; the time budget
    after the seconds left. Before the first episode lands the pace is unknown, and a time
    limit, when there is one, is taken to bind.
    """
    rate = (episodes - first) / elapsed if elapsed > 0 else 0.0
    episodes_eta = (total - episodes) / rate if rate > 0 else math.inf
    time_eta = max(limit - elapsed, 0.0) if limit > 0 else math.inf
    if limit > 0 and time_eta <= episodes_eta:
        return BudgetStatus("time", min(elapsed / limit, 1.0), time_eta)
    return BudgetStatus("episodes", min(episodes / total, 1.0), episodes_eta)


def _clock(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    minutes, secs = divmod(int(seconds), 60)
    return (
        f"{minutes // 60}:{minutes % 60:02d}:{secs:02d}"
        if minutes >= 60
        else f"{minutes}:{secs:02d}"
    )


class RunExistsError(ConfigError):
    """A new run was pointed at a directory that holds another run's records."""


def check_new_run_dir(run_dir: Path) -> None:
    """Refuse to start a new run in a directory that holds a run already.

    Why: a second run there would overwrite the first one's config and checkpoint and
    append its episodes to the same CSV files under the same episode numbers, leaving a
    record of neither. Continuing a run is ``--resume`` (``train(cfg, resume=True)``).
    """
    if not run_dir.is_dir():
        return
    found = [name for name in RUN_FILES if (run_dir / name).exists()]
    if found:
        raise RunExistsError(
            f"{run_dir} already holds a run ({', '.join(found)}): pass --resume to continue "
            "it, another --out (or --seed) for a new run, or remove the directory"
        )


LOCK_NAME = ".lock"
"""The file in a run directory that a training process holds locked while it runs."""


def make_run_dir(run_dir: Path) -> None:
    """Create the run directory (and its parents) if missing; :class:`ConfigError` naming
    ``out`` when it cannot be one. The command line calls it before Ray and the workers
    start, :class:`RunLock` whenever a trainer is built."""
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise ConfigError(f"out {str(run_dir)!r} cannot be created: {err.strerror}") from None


class RunLock:
    """An exclusive lock on a run directory for as long as one process trains in it.

    Why: two runs started at once into one directory both pass :func:`check_new_run_dir`
    before either writes a file, then interleave their records. The lock is the kernel's
    (``flock``): a process that dies releases it.
    """

    def __init__(self, run_dir: Path) -> None:
        make_run_dir(run_dir)
        try:
            self.file = (run_dir / LOCK_NAME).open("a+")
        except OSError as err:
            raise ConfigError(f"out {str(run_dir)!r}: cannot open its lock file: {err}") from None
        try:
            fcntl.flock(self.file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.file.seek(0)
            holder = self.file.read().strip() or "?"
            self.file.close()
            raise RunExistsError(
                f"{run_dir} is in use: another training process (pid {holder}) is running in "
                "it; wait for it to end, or give another --out"
            ) from None
        self.file.seek(0)
        self.file.truncate()
        self.file.write(f"{os.getpid()}\n")
        self.file.flush()

    def release(self) -> None:
        """Let another process train in the directory (idempotent)."""
        if not self.file.closed:
            fcntl.flock(self.file, fcntl.LOCK_UN)
            self.file.close()


class RecordsError(NeuronsMAEError, ValueError):
    """A file given as one of a run's CSV records is not one."""


def read_records(path: Path, needs: Sequence[str] = ()) -> list[dict[str, str]]:
    """The rows of one of a run's CSV records (``train.csv``, ``eval.csv``,
    ``episodes.csv``), as text. :class:`RecordsError` naming the file when it is not UTF-8
    CSV, or when its header lacks a column of ``needs`` (an empty file has no header yet
    and gives no rows)."""
    try:
        with path.open(newline="", encoding="utf-8") as f:
            reader = csv.DictReader(f)
            rows, columns = list(reader), reader.fieldnames
    except (UnicodeDecodeError, csv.Error) as exc:
        raise RecordsError(f"{path} is not a records CSV: {exc}") from None
    missing = [c for c in needs if columns is not None and c not in columns]
    if missing:
        raise RecordsError(
            f"{path} lacks the column(s) {missing} (it has {list(columns or [])}): "
            "not a neuronsmae-train records file"
        )
    return rows


COUNT_COLUMNS = {"train.csv": "episodes", "eval.csv": "episodes", "episodes.csv": "episode"}
"""Each CSV record's column of the episode count a row was written at."""


def trim_records(run_dir: Path, episodes: int, *, redo_final: bool = False) -> int:
    """Make a run's CSV records end where its checkpoint does, before a resumed run appends.

    Rows written after the checkpoint at ``episodes`` (a run stopped between two
    checkpoints) describe episodes the resumed run plays again from the same seeds: kept,
    they would be recorded twice and a learning curve would step back. With ``redo_final``
    (the checkpoint ends training and the resumed run evaluates it again) the test rows at
    ``episodes`` go too. A row cut short by a kill is dropped with them. Each changed file
    is rewritten whole and swapped in atomically. Returns the number of rows dropped.
    """
    dropped = 0
    for name, column in COUNT_COLUMNS.items():
        path = run_dir / name
        if not path.is_file():
            continue
        with path.open(newline="") as f:
            reader = csv.DictReader(f)
            columns, rows = reader.fieldnames, list(reader)
        kept = [r for r in rows if _before(r, column, episodes, redo_final)]
        if len(kept) == len(rows) or columns is None:
            continue
        dropped += len(rows) - len(kept)
        tmp = path.with_suffix(".tmp")
        with tmp.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns)
            writer.writeheader()
            writer.writerows(kept)
        tmp.replace(path)
    return dropped


def _before(row: dict[str, Any], column: str, episodes: int, redo_final: bool) -> bool:
    """Whether ``row`` was written at or before the checkpoint at ``episodes``."""
    try:
        at = int(row[column])
    except (KeyError, TypeError, ValueError):
        return False  # a row cut short
    if None in row or any(v is None for v in row.values()):
        return False  # too many or too few fields: cut short
    return at < episodes or (at == episodes and not (redo_final and row.get("split") == "test"))


class _Csv:
    """Append rows to a CSV file, writing the header only when the file is new."""

    def __init__(self, path: Path, columns: tuple[str, ...]) -> None:
        new = not path.exists() or path.stat().st_size == 0
        self.file = path.open("a", newline="")
        self.writer = csv.DictWriter(self.file, fieldnames=columns, extrasaction="ignore")
        if new:
            self.writer.writeheader()

    def write(self, row: dict[str, Any]) -> None:
        self.writer.writerow(row)
        self.file.flush()

    def close(self) -> None:
        self.file.close()


class Recorder:
    """Writes train and eval rows to CSV and TensorBoard and drives the progress bar."""

    def __init__(
        self,
        run_dir: Path,
        total_episodes: int,
        done_episodes: int,
        progress: bool,
        max_seconds: float = 0.0,
        purge_after: int | None = None,
    ) -> None:
        """``purge_after``: a resumed run's env steps at its checkpoint; TensorBoard hides
        the scalars logged past it before the run stopped (the CSV files are trimmed by
        :func:`trim_records`)."""
        run_dir.mkdir(parents=True, exist_ok=True)
        self.train_csv = _Csv(run_dir / "train.csv", TRAIN_COLUMNS)
        self.eval_csv = _Csv(run_dir / "eval.csv", EVAL_COLUMNS)
        self.episodes_csv = _Csv(run_dir / "episodes.csv", EPISODE_COLUMNS)
        from torch.utils.tensorboard import SummaryWriter  # 1-2 s to import: only for a run

        purge = None if purge_after is None else purge_after + 1
        self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=purge)
        self.total, self.first, self.episodes = total_episodes, done_episodes, done_episodes
        self.max_seconds = max_seconds
        self.bar = tqdm(
            total=PERMILLE,
            bar_format="{percentage:3.0f}%|{bar}| {desc}{postfix}",
            disable=not progress,
            dynamic_ncols=True,
        )
        self.last_eval: float | None = None
        self.advance(0, 0.0)

    def train(self, row: dict[str, Any]) -> None:
        """Record a training row and refresh the bar's figures."""
        self.train_csv.write(row)
        step = row["env_steps"]
        for key in (
            "epsilon",
            "train_win_rate",
            "train_return",
            "loss",
            "q_taken",
            "lr",
            "env_steps_per_s",
        ):
            if row.get(key) is not None:
                self.tb.add_scalar(f"train/{key}", row[key], step)
        self._postfix(row)

    def episode(self, number: int, info: dict[str, Any], total_reward: float, length: int) -> None:
        """Record training episode ``number`` (its ``info`` as the worker returned it)."""
        self.episodes_csv.write(
            {
                "episode": number,
                "seed": info.get("seed"),
                "epsilon": info.get("epsilon"),
                "winner": info.get("winner"),
                "return": round(total_reward, 4),
                "length": length,
                "contexts": json.dumps(info.get("contexts", {}), sort_keys=True),
                "opponent": info.get("opponent", ""),
            }
        )

    def eval(self, row: dict[str, Any]) -> None:
        """Record a greedy evaluation."""
        self.eval_csv.write(row)
        split, weights = row.get("split", "validation"), row.get("weights", "latest")
        tag = "eval" if split == "validation" else f"{split}_{weights}"
        for key in ("win_rate", "draw_rate", "mean_return"):
            self.tb.add_scalar(f"{tag}/{key}", row[key], row["env_steps"])
        self.last_eval = row["win_rate"]
        self.bar.write(
            f"{tag} @ {row['episodes']} episodes, {row['env_steps']} steps, "
            f"{row['wall_seconds']:.0f} s: greedy win rate {row['win_rate']:.2f} "
            f"(return {row['mean_return']:.1f})"
        )

    def advance(self, n: int, elapsed: float) -> None:
        """Count ``n`` more finished episodes, ``elapsed`` seconds into the session, and move
        the bar along the binding budget."""
        self.episodes += n
        status = budget_status(self.episodes, self.total, self.first, elapsed, self.max_seconds)
        spent = f"{self.episodes:,}/{self.total:,} ep"
        if self.max_seconds > 0:
            spent += f", {_clock(elapsed)}/{_clock(self.max_seconds)}"
        self.bar.set_description_str(
            f"{spent} ({status.binding} budget binds, ETA {_clock(status.eta_seconds)})",
            refresh=False,
        )
        self.bar.update(round(status.fraction * PERMILLE) - self.bar.n)

    def _postfix(self, row: dict[str, Any]) -> None:
        fig = {"sps": f"{row['env_steps_per_s']:.0f}", "win": f"{row['train_win_rate']:.2f}"}
        if row.get("loss") is not None:
            fig["loss"] = f"{row['loss']:.3f}"
        if self.last_eval is not None:
            fig["eval"] = f"{self.last_eval:.2f}"
        self.bar.set_postfix(fig, refresh=False)

    def close(self) -> None:
        """Flush and close everything."""
        self.bar.close()
        self.tb.close()
        for table in (self.train_csv, self.eval_csv, self.episodes_csv):
            table.close()
