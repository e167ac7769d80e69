"""Run records: CSV files, TensorBoard scalars and the live progress bar, in one place.

CSV is the durable record (``train.csv`` every logged round, ``eval.csv`` every greedy
evaluation; a resumed run appends), TensorBoard the convenient one, and tqdm shows a person
watching the run what it is doing now: episodes, env steps/s, win rate and loss.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

TRAIN_COLUMNS = (
    "episodes",
    "env_steps",
    "updates",
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
    "mean_return",
    "eval_episodes",
    "split",
    "weights",
)
"""Columns of ``eval.csv`` (greedy play on held-out seeds): ``split`` is ``validation``
(periodic) or ``test`` (final); ``weights`` is ``latest`` or ``best`` (see ``keep_best``)."""


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
        self, run_dir: Path, total_episodes: int, done_episodes: int, progress: bool
    ) -> None:
        run_dir.mkdir(parents=True, exist_ok=True)
        self.train_csv = _Csv(run_dir / "train.csv", TRAIN_COLUMNS)
        self.eval_csv = _Csv(run_dir / "eval.csv", EVAL_COLUMNS)
        self.tb = SummaryWriter(str(run_dir / "tb"))
        self.bar = tqdm(
            total=total_episodes,
            initial=done_episodes,
            unit="ep",
            disable=not progress,
            dynamic_ncols=True,
            smoothing=0.05,
        )
        self.last_eval: float | None = None

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

    def advance(self, n: int) -> None:
        """Move the bar by ``n`` finished episodes."""
        self.bar.update(n)

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
        self.train_csv.close()
        self.eval_csv.close()
