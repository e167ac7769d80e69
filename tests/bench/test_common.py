"""The benchmarks' CPU clocks: per thread, to the scheduler's precision."""

from __future__ import annotations

import os
import threading
import time

import psutil

from bench.common import cpu_between, cpu_by_thread, cpu_snapshot


def _burn(seconds: float) -> None:
    end = time.thread_time() + seconds
    while time.thread_time() < end:
        pass


def test_the_main_thread_reads_what_thread_time_reads() -> None:
    me = psutil.Process()
    before, t0 = cpu_snapshot([me]), time.thread_time()
    _burn(0.05)
    spent, after = time.thread_time() - t0, cpu_snapshot([me])
    main = cpu_between(before, after, main=True)
    assert abs(main - spent) < 0.005  # the same clock, read a few µs apart
    assert 0.05 <= main < 0.2


def test_a_thread_born_in_between_counts_from_zero_and_apart_from_main() -> None:
    me = psutil.Process()
    burned, release = threading.Event(), threading.Event()

    def work() -> None:
        _burn(0.05)
        burned.set()
        release.wait(10)

    before = cpu_snapshot([me])
    worker = threading.Thread(target=work)
    worker.start()
    try:
        assert burned.wait(10)
        seen = cpu_snapshot([me])  # the thread is alive, idle, its 0.05 s burned
    finally:
        release.set()
        worker.join()
    [[main, other]] = cpu_by_thread(before, seen, [me.pid])
    assert 0.05 <= other < 0.2  # counted from zero: it did not exist in ``before``
    assert main < 0.05  # the main thread only waited
    assert abs(cpu_between(before, seen) - (main + other)) < 1e-9
    # The thread has ended: it counts not at all, so what remains is the main thread's.
    # ``join`` returns a moment before the kernel drops the thread from /proc: wait for that.
    deadline = time.monotonic() + 5
    while os.path.exists(f"/proc/{me.pid}/task/{worker.native_id}") and time.monotonic() < deadline:
        time.sleep(0.001)
    after = cpu_snapshot([me])
    assert (me.pid, worker.native_id) not in after
    assert 0.0 <= cpu_between(seen, after) < 0.05
