"""The benchmarks' CPU clocks (per thread, to the scheduler's precision) and their argparse
types."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import psutil
import pytest

from bench.common import (
    MAX_ARENAS,
    arena_count,
    at_least,
    between,
    cpu_between,
    cpu_by_thread,
    cpu_snapshot,
    finite,
    non_negative,
    positive,
    tcp_port,
)


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


def test_at_least_refuses_counts_below_the_bound_by_name() -> None:
    assert at_least(0)("0") == 0 and at_least(1)("8") == 8
    with pytest.raises(argparse.ArgumentTypeError, match="must be at least 1, got 0"):
        at_least(1)("0")
    with pytest.raises(argparse.ArgumentTypeError, match="expected an integer, got 'x'"):
        at_least(1)("x")


def _refusal(parse: Callable[[str], object], text: str) -> str:
    """The message ``parse`` refuses ``text`` with."""
    with pytest.raises(argparse.ArgumentTypeError) as refused:
        parse(text)
    return str(refused.value)


def test_between_takes_both_bounds_and_refuses_past_either_naming_them() -> None:
    assert [between(0, 8)(t) for t in ("0", "8")] == [0, 8]
    assert _refusal(between(0, 8), "-1") == "must be in [0, 8], got -1"
    assert _refusal(between(0, 8), "9") == "must be in [0, 8], got 9"
    assert _refusal(between(0, 8), "2.5") == "expected an integer, got '2.5'"


def test_ports_and_arena_counts_have_their_protocol_bounds() -> None:
    assert tcp_port("1") == 1 and tcp_port("65535") == 65535
    assert _refusal(tcp_port, "0") == "must be in [1, 65535], got 0"
    assert _refusal(tcp_port, "65536") == "must be in [1, 65535], got 65536"
    assert arena_count("1") == 1 and arena_count(str(MAX_ARENAS)) == MAX_ARENAS
    assert _refusal(arena_count, "0") == f"must be in [1, {MAX_ARENAS}], got 0"
    too_many = MAX_ARENAS + 1
    assert _refusal(arena_count, str(too_many)) == f"must be in [1, {MAX_ARENAS}], got {too_many}"


def test_positive_refuses_zero_negatives_nan_and_infinities_naming_the_bound() -> None:
    assert positive("0.25") == 0.25 and positive("3") == 3.0 and positive("1e-3") == 0.001
    for text, shown in (("0", "0.0"), ("-2", "-2.0"), ("nan", "nan"), ("inf", "inf")):
        assert _refusal(positive, text) == f"must be a finite number above 0, got {shown}"
    assert _refusal(positive, "soon") == "expected a number, got 'soon'"


def test_non_negative_takes_zero_and_refuses_below_it_or_unbounded() -> None:
    assert non_negative("0") == 0.0 and non_negative("30") == 30.0
    for text in ("-0.5", "-inf", "inf", "nan"):
        want = f"must be a finite number of at least 0, got {float(text)}"
        assert _refusal(non_negative, text) == want


def test_finite_with_a_maximum_names_the_whole_range() -> None:
    closed, half_open = finite(0.0, 100.0), finite(0.0, 100.0, above=True)
    assert closed("0") == 0.0 and closed("100") == 100.0 and half_open("100") == 100.0
    assert _refusal(closed, "100.5") == "must be a finite number in [0, 100], got 100.5"
    assert _refusal(half_open, "0") == "must be a finite number in (0, 100], got 0.0"


def test_a_parser_refuses_a_bad_list_item_naming_the_argument(
    capsys: pytest.CaptureFixture[str],
) -> None:
    parser = argparse.ArgumentParser(prog="bench")
    parser.add_argument("--envs", type=arena_count, nargs="+", default=[1, 8])
    parser.add_argument("--seconds", type=positive, default=3.0)
    assert parser.parse_args(["--envs", "1", str(MAX_ARENAS)]).envs == [1, MAX_ARENAS]
    with pytest.raises(SystemExit) as exit_:
        parser.parse_args(["--envs", "4", "0"])
    assert exit_.value.code == 2
    assert f"argument --envs: must be in [1, {MAX_ARENAS}], got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parser.parse_args(["--seconds", "0"])
    assert "argument --seconds: must be a finite number above 0, got 0.0" in capsys.readouterr().err


def test_the_commit_is_the_checkout_s_wherever_the_command_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from bench.common import commit

    monkeypatch.delenv("NEURONSMAE_COMMIT", raising=False)
    here = commit()
    monkeypatch.chdir(tmp_path)  # outside any checkout: was "" or "unknown"
    assert commit() == here and len(here) == 40
    monkeypatch.setenv("NEURONSMAE_COMMIT", "abc123")  # a git-archive snapshot
    assert commit() == "abc123"


def test_a_git_archive_snapshot_knows_its_commit(tmp_path: Path) -> None:
    """``git archive`` expands bench/ARCHIVE_COMMIT (export-subst), so a snapshot run with no
    history and no ``$NEURONSMAE_COMMIT`` still records the commit it was made from."""
    repo = Path(__file__).resolve().parents[2]
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                          check=True, cwd=repo).stdout.strip()  # fmt: skip
    archive = subprocess.run(["git", "archive", "HEAD", "bench"], capture_output=True,
                             check=True, cwd=repo).stdout  # fmt: skip
    subprocess.run(["tar", "-x", "-C", str(tmp_path)], input=archive, check=True)
    env = {k: v for k, v in os.environ.items() if k != "NEURONSMAE_COMMIT"}
    env["GIT_CEILING_DIRECTORIES"] = str(tmp_path.parent)  # no checkout above the snapshot
    code = "from bench.common import commit; print(commit())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=tmp_path, env=env)  # fmt: skip
    assert out.stdout.strip() == head


def test_the_snapshot_reads_the_calling_thread_to_the_microsecond() -> None:
    """The scheduler refreshes a running thread's schedstat only at its next tick: read
    there, the thread taking the snapshot lagged by up to a tick (1-3 % of a round)."""
    from bench.common import cpu_between, cpu_snapshot

    me = psutil.Process()
    errors = []
    for _ in range(10):
        before, start = cpu_snapshot([me]), time.thread_time()
        sum(i * i for i in range(200_000))  # ~10 ms on the CPU, no clock read inside
        after, end = cpu_snapshot([me]), time.thread_time()
        errors.append(abs(cpu_between(before, after, main=True) - (end - start)))
    assert max(errors) < 2e-4


def test_ports_come_from_the_block_outside_the_ephemeral_range(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A port picked in the kernel's ephemeral range can be taken by an outgoing connection
    before the server binds it (the cluster test failed so in CI)."""
    import bench.common as common

    base = common.free_ports(3)
    assert base in common.PORT_BLOCK and base + 2 in common.PORT_BLOCK
    assert all(common.port_is_free(base + i) for i in range(3))
    monkeypatch.setattr(common, "ephemeral_ports", lambda: range(20000, 61000))
    with pytest.raises(RuntimeError, match="overlap the kernel's ephemeral range 20000-60999"):
        common.free_ports(2)
    assert common.port_is_free(common.free_port())  # benches fall back to the kernel's pick
