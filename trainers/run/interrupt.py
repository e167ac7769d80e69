"""Stop a training run cleanly on Ctrl-C or SIGTERM.

The first SIGINT or SIGTERM asks the run to stop: the training loop ends after the episodes
it is absorbing, the trainer saves ``checkpoint.pt`` and raises :class:`TrainingInterrupted`
instead of running the final evaluation, and ``neuronsmae-train --resume`` continues from
there with nothing lost or recorded twice. A second signal interrupts at once
(``KeyboardInterrupt``), and the run continues from its last periodic checkpoint.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from types import FrameType, TracebackType
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""The signals that ask a run to stop."""
POLL_SECONDS = 1.0
"""Longest wait for landing episodes between two looks at a stop request."""


class TrainingInterrupted(Exception):
    """The run stopped on a signal after saving its checkpoint; ``--resume`` continues it."""

    def __init__(self, run_dir: Path, episodes: int, signal_name: str) -> None:
        self.run_dir, self.episodes, self.signal_name = run_dir, episodes, signal_name
        super().__init__(
            f"{signal_name}: stopped at {episodes} episodes, checkpoint saved in {run_dir}; "
            f"continue with the same command and --resume (--out {run_dir})"
        )


class StopSignals:
    """While entered, turns the first SIGINT or SIGTERM into a stop request.

    ``requested`` is the first signal's name (empty until one arrives). Signal handlers can
    only be installed by the main thread: entered in another thread, this does nothing and
    signals keep their usual effect.
    """

    def __init__(self, who: str = "neuronsmae-train") -> None:
        self.who = who
        self.requested = ""
        self._saved: dict[int, Any] = {}

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._saved[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for sig, handler in self._saved.items():
            signal.signal(sig, handler)
        self._saved.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if self.requested:
            raise KeyboardInterrupt(f"{name} again: stopping at once")
        self.requested = name
        print(
            f"\n{self.who}: {name}: stopping after the episodes in hand and saving a checkpoint "
            "(send it again to stop at once)",
            file=sys.stderr,
            flush=True,
        )
