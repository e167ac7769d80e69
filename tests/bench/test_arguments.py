"""The benchmark scripts refuse nonsense arguments in parse_args, before any work starts."""

from __future__ import annotations

import sys
from types import ModuleType
from typing import Any

import pytest

from bench import (
    bench_env,
    bench_learning,
    bench_sampling,
    bench_scaling,
    bench_transport,
    bench_vector,
    soak,
    zenoh_floor,
)
from bench.common import MAX_ARENAS

TOO_MANY = str(MAX_ARENAS + 1)


class Started(Exception):
    """The script got past its arguments to the work (stubbed out here)."""


def _start(*args: Any, **kwargs: Any) -> Any:
    raise Started


WORK = {
    bench_env: "bare_runners",
    bench_vector: "run",
    bench_transport: "compare",
    bench_scaling: "measure",
    soak: "soak",
    zenoh_floor: "measure",
}
"""The first costly call of each script's main, which a test must never reach for real."""


def _main(script: ModuleType, argv: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Run ``script``'s main on ``argv`` with its work replaced by :func:`_start`."""
    monkeypatch.setattr(script, WORK[script], _start)
    if script is zenoh_floor:
        for kind in zenoh_floor.SERVERS:
            monkeypatch.setitem(zenoh_floor.SERVERS, kind, _start)
    monkeypatch.setattr(sys, "argv", [script.__name__, *argv])
    script.main()


@pytest.mark.parametrize(
    ("script", "argv", "message"),
    [
        (bench_env, ["--repeats", "0"], "argument --repeats: must be at least 1, got 0"),
        (
            bench_env,
            ["--seconds", "nan"],
            "argument --seconds: must be a finite number of at least",
        ),
        (bench_vector, ["--envs", "4", TOO_MANY], f"--envs: must be in [1, {MAX_ARENAS}]"),
        (bench_vector, ["--pingpong-decisions", "-1"], "must be at least 0, got -1"),
        (bench_transport, ["--busy-poll-us", "2000", "-5"], "in [0, 100000], got -5.0"),
        (bench_scaling, ["--base-port", "0"], "argument --base-port: must be in [1, 65535]"),
        (
            bench_scaling,
            ["--base-port", "65534", "--counts", "1", "4"],
            "--base-port 65534 with --counts up to 4 puts servers past port 65535",
        ),
        (soak, ["--window", "2"], "argument --window: must be at least 500, got 2"),  # 0 CPU
        (bench_env, ["--seconds", "1e-9"], "--seconds: must be a finite number of at least 0.05"),
        (bench_vector, ["--envs", "2", "2"], "--envs gives 2 twice: give each value once"),
        (bench_scaling, ["--counts", "1", "1"], "--counts gives 1 twice"),
        (bench_transport, ["--busy-poll-us", "500", "500"], "--busy-poll-us gives 500.0 twice"),
        (soak, ["--envs", TOO_MANY], f"argument --envs: must be in [1, {MAX_ARENAS}]"),
        (zenoh_floor, ["--arenas", "-1"], f"--arenas: must be in [0, {MAX_ARENAS}], got -1"),
        (zenoh_floor, ["--serve", "tcp"], "--serve needs --port"),
    ],
)
def test_a_script_refuses_a_bad_value_before_starting(
    script: ModuleType,
    argv: list[str],
    message: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit) as exit_:
        _main(script, argv, monkeypatch)
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize(
    ("script", "argv"),
    [
        (bench_vector, ["--pingpong-decisions", "0", "--envs", "1", str(MAX_ARENAS)]),
        (bench_scaling, ["--base-port", "65532", "--counts", "4"]),
        (soak, ["--warmup", "0", "--rebuilds", "0", "--decisions", "1000", "--window", "500"]),
        (zenoh_floor, ["--arenas", "0"]),
    ],
)
def test_a_script_takes_the_edges_of_its_ranges(
    script: ModuleType, argv: list[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    with pytest.raises(Started):
        _main(script, argv, monkeypatch)


def test_the_learning_bench_takes_zero_for_none_and_auto_but_refuses_unbounded_minutes() -> None:
    args = bench_learning.parse_args(["--minutes", "0", "--workers", "0", "--eval-every", "0"])
    assert (args.minutes, args.workers, args.eval_every) == (0.0, 0, 0)
    for bad in (["--minutes", "inf"], ["--episodes", "0"], ["--seed", "-1"]):
        with pytest.raises(SystemExit):
            bench_learning.parse_args(bad)


def test_sampling_refuses_more_servers_than_a_served_worker_has_arenas(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(SystemExit):
        bench_sampling._args(["--envs", "1", "2", "8", "--servers", "1", "3"])
    assert "got --servers 3 with --envs 2" in capsys.readouterr().err
    # One arena per worker, or no served rows: every row uses one server.
    assert bench_sampling._args(["--envs", "1", "--servers", "3"]).servers == [3]
    assert bench_sampling._args(["--env", "inprocess", "--envs", "2", "--servers", "3"])
    with pytest.raises(SystemExit):
        bench_sampling._args(["--env", "ray"])


@pytest.mark.parametrize(
    ("content", "argv", "message"),
    [
        ("not json", ["--report"], "is not a table this script wrote: Expecting value"),
        ("[1]", ["--report"], "is JSON but holds no list of 'records'"),
        (None, ["--test-at", "foo"], "argument --test-at: contexts: 'foo' is not key=value"),
        (None, ["--test-at", "coef=0.5..1"], "evaluation contexts must be fixed; ['coef'] vary"),
        (None, ["--set", "lr"], "--set expects key=value, got 'lr'"),
        (None, ["--set", "lr=nan"], "lr must be a finite number, got nan"),
    ],
)
def test_the_paper_table_refuses_a_bad_table_or_setting_before_any_run(
    content: str | None,
    argv: list[str],
    message: str,
    tmp_path: Any,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """These were tracebacks (a foreign --out file, --test-at), or a --set typo surfaced
    only when the first 30-minute cell was configured."""
    from bench import paper_table

    out = tmp_path / "table.json"
    if content is not None:
        out.write_text(content)
    monkeypatch.setattr(paper_table, "run_cell", _start)
    with pytest.raises(SystemExit) as exit_:
        paper_table.main(["--out", str(out), "--runs", str(tmp_path / "runs"), *argv])
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
    if content is not None:
        assert out.read_text() == content  # never overwritten


def test_scaling_refuses_a_base_port_in_use_before_any_fleet(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import socket

    with socket.socket() as taken:  # a FleetStartError traceback minutes into the run
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = str(taken.getsockname()[1])
        with pytest.raises(SystemExit):
            _main(bench_scaling, ["--counts", "1", "--base-port", port], monkeypatch)
    assert f"port {port} on 127.0.0.1 is already in use" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("module", "argv", "message"),
    [
        ("fuzz", ["--timeout", "0.0001"], "--timeout: must be a finite number of at least 0.5"),
        ("fuzz", ["--arenas", "1", "1"], "--arenas gives 1 twice"),
        ("faults", ["--skip", "servers", "ray", "learner"], "--skip leaves no part to run"),
        ("bench_dynamics", ["--keys"], "--keys: expected at least one argument"),  # wrote 0 rows
        ("bench_sampling", ["--envs", "2", "--groups", "3"], "--groups must not exceed --envs"),
    ],
)
def test_more_scripts_refuse_a_run_that_cannot_mean_anything(
    module: str,
    argv: list[str],
    message: str,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    import importlib

    script = importlib.import_module(f"bench.{module}")
    monkeypatch.setattr(sys, "argv", [module, *argv])
    with pytest.raises(SystemExit) as exit_:
        script._args(argv) if module == "bench_sampling" else script.main()
    assert exit_.value.code == 2
    assert message in capsys.readouterr().err
