"""The decoupled learner keeps to its replay ratio, never drops an episode, and hands its
failures to the driver."""

from __future__ import annotations

import threading
import time

import pytest

from neuronsmae.trainers.run.decoupled import LearnerThread


class FakeLearner:
    """Counts updates; each takes ``seconds``."""

    def __init__(self, seconds: float = 0.0, fail_at: int | None = None) -> None:
        self.updates, self.seconds, self.fail_at = 0, seconds, fail_at

    def train(self, batch: object) -> dict[str, float]:
        if self.fail_at is not None and self.updates == self.fail_at:
            raise ValueError("a NaN in the loss")
        time.sleep(self.seconds)
        self.updates += 1
        return {"loss": float(self.updates)}


def _thread(learner: FakeLearner, ratio: float = 2.0, starts: int = 4) -> LearnerThread:
    return LearnerThread(
        learner,  # type: ignore[arg-type]
        lambda: object(),
        ratio=ratio,
        tolerance=0.1,
        learning_starts=starts,
        lock=threading.Lock(),
    )


def _until(condition, seconds: float = 5.0) -> None:  # type: ignore[no-untyped-def]
    end = time.monotonic() + seconds
    while not condition() and time.monotonic() < end:
        time.sleep(0.005)


def test_the_learner_trains_to_the_ratio_and_waits_for_episodes() -> None:
    learner = FakeLearner()
    thread = _thread(learner)
    thread.start()
    try:
        thread.stored(3)  # below learning_starts: nothing due
        time.sleep(0.1)
        assert learner.updates == 0
        thread.stored(14)  # 10 past learning_starts: 20 due, 2 (one episode's) ahead allowed
        _until(lambda: learner.updates >= 22)
        time.sleep(0.1)
        assert learner.updates == 22 and thread.ahead() and not thread.behind()
        assert thread.idle_seconds > 0
    finally:
        thread.stop()
    assert thread.last_stats == {"loss": 22.0}


def test_a_slow_learner_is_behind_and_the_driver_throttles() -> None:
    learner = FakeLearner(seconds=0.05)
    thread = _thread(learner, ratio=4.0, starts=0)
    thread.start()
    try:
        thread.stored(100)  # 400 due; at 20 updates/s it is far behind
        time.sleep(0.05)
        assert thread.behind()
    finally:
        thread.stop()
    assert thread.busy_seconds > 0


def test_a_resumed_learner_counts_only_this_sessions_updates() -> None:
    learner = FakeLearner()
    learner.updates = 1000  # from the checkpoint
    thread = _thread(learner, ratio=1.0, starts=0)
    assert thread.target() == 1000 and not thread.behind()
    thread.start()
    try:
        thread.stored(5)
        _until(lambda: learner.updates >= 1006)
        assert learner.updates == 1006  # 5 due, one ahead allowed
    finally:
        thread.stop()


def test_a_failing_update_reaches_the_driver() -> None:
    thread = _thread(FakeLearner(fail_at=3), starts=0)
    thread.start()
    thread.stored(10)
    _until(lambda: thread.error is not None)
    with pytest.raises(RuntimeError, match=r"learner thread failed.*NaN"):
        thread.check()
    with pytest.raises(RuntimeError):
        thread.stop()


def test_a_driver_waiting_for_a_lagging_learner_blocks_instead_of_polling() -> None:
    learner = FakeLearner(seconds=0.005)
    thread = _thread(learner, ratio=1.0, starts=0)
    thread.start()
    try:
        thread.stored(40)  # 40 due, 4 of slack: behind until 36
        assert thread.behind()
        start = time.perf_counter()
        thread.catch_up(5.0)
        assert not thread.behind() and learner.updates >= 36
        assert time.perf_counter() - start < 2.0
        start = time.perf_counter()
        thread.catch_up(5.0)  # not behind: returns at once
        assert time.perf_counter() - start < 0.1
    finally:
        thread.stop()
