"""BenchMARL callbacks for NeuronsMAE runs: a wall-clock budget.

BenchMARL budgets an experiment in frames or iterations; a benchmark on a shared machine
budgets it in minutes, like ``neuronsmae-train --set max_minutes=30``. The callback is a
module-level class because BenchMARL pickles an experiment's callbacks into its
``config.pkl``.
"""

from __future__ import annotations

import time
from typing import Any

from benchmarl.experiment.callback import Callback


class BudgetSpent(Exception):
    """Raised by :class:`WallClock` to end an experiment whose time is up (after saving
    its checkpoint); ``Experiment.run`` closes the experiment and re-raises it."""


class WallClock(Callback):
    """Save the experiment and stop it after the training step that spends ``minutes`` of
    wall time since setup."""

    def __init__(self, minutes: float) -> None:
        super().__init__()
        if not minutes > 0:
            raise ValueError(f"minutes must be > 0, got {minutes!r}")
        self.minutes = minutes
        self.start = time.perf_counter()

    def on_setup(self) -> None:
        self.start = time.perf_counter()

    def on_train_end(self, training_td: Any, group: str) -> None:
        if time.perf_counter() - self.start >= 60.0 * self.minutes:
            self.experiment._save_experiment()  # BenchMARL's checkpoint of the experiment
            raise BudgetSpent(f"{self.minutes:g} minutes spent")
