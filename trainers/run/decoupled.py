"""Learning decoupled from sampling: the learner trains in a thread of its own.

With ``learner.replay_ratio`` > 0 the trainer's driver thread only samples: it keeps the
workers' queues full, stores the episodes that land, evaluates and checkpoints, while a
:class:`LearnerThread` draws batches and updates the networks beside it (torch releases the
GIL in its kernels, so the two overlap on separate cores). The replay ratio holds them
together: after ``E`` stored episodes the learner aims at ``ratio × (E − learning_starts)``
updates. It runs ahead of that by at most ``tolerance`` (then waits for episodes), and when
it falls behind by more, the driver stops handing out new episodes until it catches up (the
workers finish what they hold). Nothing is dropped: every episode that lands is stored.

The learner's state is read (acting weights for the workers, checkpoints, evaluations)
under :attr:`LearnerThread.lock`, which an update holds for its duration, so a read never
sees half an optimiser step. The interleaving of updates and episodes follows the timing of
the machine, so a decoupled run is not bit-for-bit reproducible from its seed (the inline
loop is).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from neuronsmae.trainers.core.buffer import Batch
from neuronsmae.trainers.core.learner import QLearner

IDLE_WAIT = 0.05
"""Seconds the learner waits for more episodes before it checks its stop flag again."""


class LearnerThread:
    """Updates ``learner`` from batches of ``make_batch`` at ``ratio`` updates per stored
    episode (see the module docstring)."""

    def __init__(
        self,
        learner: QLearner,
        make_batch: Callable[[], Batch],
        *,
        ratio: float,
        tolerance: float,
        learning_starts: int,
        lock: threading.Lock,
    ) -> None:
        self.learner, self.make_batch = learner, make_batch
        self.ratio, self.tolerance, self.learning_starts = ratio, tolerance, learning_starts
        self.lock = lock
        """Held by every update, and by whoever reads the learner's state."""
        self.base = learner.updates
        """The learner's updates when the thread began (a resumed run's are not due again)."""
        self._wake = threading.Condition()
        """Wakes the thread when episodes are stored or it is to stop."""
        self._progress = threading.Condition()
        """Wakes a driver waiting for the thread to catch up (:meth:`catch_up`)."""
        self._stored = 0
        self._stop = False
        self.error: BaseException | None = None
        """What stopped the thread, if anything did: re-raised by :meth:`check`."""
        self.last_stats: dict[str, float] = {}
        self.busy_seconds = 0.0
        """Time spent in updates (drawing batches included)."""
        self.idle_seconds = 0.0
        """Time spent waiting for episodes (the learner ahead of the ratio)."""
        self._thread = threading.Thread(target=self._run, name="learner", daemon=True)

    # --- the ratio ------------------------------------------------------------------------
    def target(self) -> float:
        """Updates due for the episodes stored in this session (:meth:`stored`)."""
        return self.base + self.ratio * max(0, self._stored - self.learning_starts)

    def _slack(self) -> float:
        return max(self.ratio, self.tolerance * (self.target() - self.base))

    def ahead(self) -> bool:
        """The learner has done all it may until more episodes come."""
        return self.learner.updates >= self.target() + self._slack()

    def behind(self) -> bool:
        """The learner lags the ratio by more than its tolerance: sampling should wait."""
        return self.learner.updates < self.target() - self._slack()

    # --- the driver's side ----------------------------------------------------------------
    def start(self) -> None:
        self._thread.start()

    def stored(self, episodes: int) -> None:
        """The driver has stored ``episodes`` episodes in this session."""
        with self._wake:
            self._stored = episodes
            self._wake.notify()

    def stop(self) -> None:
        """Finish the update in hand and end the thread (re-raising what stopped it)."""
        with self._wake:
            self._stop = True
            self._wake.notify()
        if self._thread.is_alive():
            self._thread.join()
        self.check()

    def catch_up(self, timeout: float) -> None:
        """Block until the learner is no longer :meth:`behind` (or has failed, or
        ``timeout`` seconds pass): the driver waits here instead of polling, since a busy
        driver thread would take the interpreter from the learner's between its kernels."""
        with self._progress:
            self._progress.wait_for(
                lambda: not self.behind() or self.error is not None or not self._thread.is_alive(),
                timeout,
            )

    def check(self) -> None:
        """Re-raise in the driver whatever ended the learner thread."""
        if self.error is not None:
            raise RuntimeError(f"the learner thread failed: {self.error!r}") from self.error

    # --- the thread -----------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while self._next():
                start = time.perf_counter()
                batch = self.make_batch()
                with self.lock:
                    self.last_stats = self.learner.train(batch)
                self.busy_seconds += time.perf_counter() - start
                with self._progress:
                    self._progress.notify_all()
        except BaseException as exc:  # handed to the driver by check()
            self.error = exc
            with self._progress:
                self._progress.notify_all()

    def _next(self) -> bool:
        """Wait until an update is due (True) or the thread is to stop (False)."""
        with self._wake:
            while not self._stop:
                ready = self._stored >= max(self.learning_starts, 1)
                if ready and not self.ahead():
                    return True
                start = time.perf_counter()
                self._wake.wait(IDLE_WAIT)
                self.idle_seconds += time.perf_counter() - start
            return False

    def figures(self) -> dict[str, Any]:
        """The thread's timings for the records."""
        return {"learner_busy_seconds": self.busy_seconds,
                "learner_idle_seconds": self.idle_seconds}  # fmt: skip
