"""The fleet's state file: only the fleet that owns it writes it, a bad
``$NEURONSMAE_STATE_DIR`` is refused before any server starts, ``status`` survives a
malformed file, and a fleet stopped while starting does not call its servers slow."""

from __future__ import annotations

import json
import logging
import os
import socket
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from neuronsmae.protocol.launch import ServerCommand
from neuronsmae.server.serving import supervisor
from neuronsmae.server.serving.fleet import main, read_state
from neuronsmae.server.serving.statefile import pid_alive
from neuronsmae.server.serving.supervisor import Fleet, FleetSpec, StopFlag

from .conftest import free_test_ports, listening, stop, wait_for

Spawn = Callable[..., subprocess.Popen[bytes]]


@pytest.fixture
def running_fleet() -> Iterator[int]:
    """The pid of a live process standing for a running fleet (it only sleeps)."""
    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    yield proc.pid
    stop(proc)


@pytest.fixture
def no_spawn(monkeypatch: pytest.MonkeyPatch) -> None:
    """Fail the test if any fleet starts a server."""

    def refuse(self: Fleet, member: object) -> None:
        raise AssertionError("a server was started")

    monkeypatch.setattr(supervisor.Fleet, "_spawn", refuse)


def _state_of(fleet_pid: int, port: int) -> str:
    """The state file a running fleet on ``port`` writes (as Fleet does)."""
    server = {"port": port, "seed": 1, "pid": fleet_pid, "starts": 1, "log": "x.log"}
    return json.dumps({"fleet_pid": fleet_pid, "spec": {}, "servers": [server]}, indent=1)


def _run(base: int, logs: Path, *extra: str) -> int:
    argv = ["--base-port", str(base), "--count", "1", "--time-scale", "0"]
    return main([*argv, "--log-dir", str(logs), *extra])


class Sleeper(ServerCommand):
    """Started like a server, but never answers a ping."""

    def argv(self) -> list[str]:
        return [sys.executable, "-c", "import time; time.sleep(60)"]


def _sleeping_fleet(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Fleet:
    fleet = Fleet(
        FleetSpec(base_port=free_test_ports()), tmp_path / "logs", tmp_path / "state.json", 0.2
    )
    monkeypatch.setattr(fleet, "command", lambda member: Sleeper(member.port))
    return fleet


# ---- only the owner writes ---------------------------------------------------------------


@pytest.mark.usefixtures("no_spawn")
def test_a_fleet_that_cannot_start_leaves_the_running_fleets_state_alone(
    running_fleet: int,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The defect: the second fleet's exit path marked the first one's servers stopped."""
    base = free_test_ports()
    monkeypatch.setenv("NEURONSMAE_STATE_DIR", str(tmp_path))
    state = tmp_path / f"neuronsmae-serve-{base}.json"
    text = _state_of(running_fleet, base)
    state.write_text(text)
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", base))
        squatter.listen()
        assert _run(base, tmp_path / "logs") == 2
    assert "already in use" in caplog.text
    assert state.read_text() == text
    assert read_state(state)[base]["pid"] == running_fleet


@pytest.mark.usefixtures("no_spawn")
def test_a_fleet_refuses_the_state_file_of_another_running_fleet(
    running_fleet: int, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Same base port, free ports (another --host, say): both fleets would share the file."""
    base, state = free_test_ports(), tmp_path / "state.json"
    text = _state_of(running_fleet, base)
    state.write_text(text)
    assert _run(base, tmp_path / "logs", "--state-file", str(state)) == 2
    assert f"{state} belongs to a running fleet (pid {running_fleet})" in caplog.text
    assert state.read_text() == text


@pytest.mark.usefixtures("no_spawn")
@pytest.mark.parametrize("text", ["my notes\n", '{"servers": [1, 2]}', "[]"])
def test_a_fleet_never_overwrites_a_file_that_is_no_fleets_state(
    text: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    state = tmp_path / "state.json"
    state.write_text(text)
    assert _run(free_test_ports(), tmp_path / "logs", "--state-file", str(state)) == 2
    assert f"{state} is not" in caplog.text and "not overwriting it" in caplog.text
    assert state.read_text() == text


def test_a_fleet_takes_over_a_stale_state_file_and_marks_its_servers_stopped(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a fleet that has exited
    fleet = _sleeping_fleet(tmp_path, monkeypatch)
    fleet.state_file.write_text(_state_of(gone.pid, fleet.spec.base_port))
    with fleet:
        fleet.start(timeout=0.3)
        recorded = read_state(fleet.state_file)[fleet.spec.base_port]
        assert recorded["pid"] == fleet.members[0].pid and recorded["starts"] == 1
        assert not list(tmp_path.glob("*.tmp"))
    after = json.loads(fleet.state_file.read_text())
    assert after["fleet_pid"] is None and after["servers"][0]["pid"] is None


# ---- the state folder ----------------------------------------------------------------------


@pytest.mark.usefixtures("no_spawn")
@pytest.mark.parametrize("kind", ["missing", "a file"])
def test_a_bad_state_dir_is_a_usage_error_before_anything_starts(
    kind: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    folder = tmp_path / "nonexistent"
    if kind == "a file":
        folder.write_text("")
    monkeypatch.setenv("NEURONSMAE_STATE_DIR", str(folder))
    with pytest.raises(SystemExit) as exc:
        _run(free_test_ports(), tmp_path / "logs")
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert f"NEURONSMAE_STATE_DIR={folder}: {folder} " in err and "existing folder" in err
    assert folder.exists() == (kind == "a file")  # not created
    assert not (tmp_path / "logs").exists()


@pytest.mark.usefixtures("no_spawn")
def test_an_unwritable_state_file_stops_the_fleet_before_any_server(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    base = free_test_ports()
    monkeypatch.setenv("NEURONSMAE_STATE_DIR", str(tmp_path))
    (tmp_path / f"neuronsmae-serve-{base}.json").mkdir()  # where the file should go
    assert _run(base, tmp_path / "logs") == 2
    assert f"neuronsmae-serve-{base}.json cannot be read" in caplog.text


@pytest.mark.parametrize(
    "servers",
    [[1, 2], [{"port": "28001"}], [{"port": None}], [{"port": True}], [{}], [{"port": 70000}]],
)
def test_status_names_a_malformed_state_file_and_still_reports(
    servers: list[object],
    tmp_path: Path,
    caplog: pytest.LogCaptureFixture,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """``"servers": [1, 2]`` of a live fleet used to end ``status`` in a TypeError."""
    state = tmp_path / "state.json"
    state.write_text(json.dumps({"fleet_pid": os.getpid(), "servers": servers}))
    argv = ["status", "--base-port", str(free_test_ports()), "--state-file", str(state)]
    with caplog.at_level(logging.WARNING, logger="neuronsmae.serve"):
        assert main([*argv, "--json", "--ping-timeout", "0.5"]) == 1
    assert f"fleet state file {state} is not a fleet's state: servers[0]" in caplog.text
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["state"] == "down" and rows[0]["pid"] is None


@pytest.mark.parametrize("pid", [0, -1, True, 2**70, "1", None])
def test_only_a_positive_pid_can_be_alive(pid: object) -> None:
    """``kill(0, 0)`` and ``kill(-1, 0)`` succeed (they name process groups): a state file
    saying ``"fleet_pid": 0`` made a fleet that never ran look alive."""
    assert not pid_alive(pid)


# ---- stopping while starting -------------------------------------------------------------


def test_a_fleet_stopped_while_starting_does_not_call_its_servers_slow(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    fleet = _sleeping_fleet(tmp_path, monkeypatch)
    with caplog.at_level(logging.INFO, logger="neuronsmae.serve"), fleet:
        fleet.start(timeout=0.5)  # the control: not stopped, so it is said
    assert "is not answering yet" in caplog.text
    caplog.clear()

    fleet = _sleeping_fleet(tmp_path, monkeypatch)
    flag = StopFlag()
    timer = threading.Timer(0.5, lambda: setattr(flag, "set", True))
    with caplog.at_level(logging.INFO, logger="neuronsmae.serve"), fleet:
        timer.start()
        fleet.start(timeout=60, stop=flag)
        assert flag.set and fleet.members[0].alive()
    timer.join()
    assert "started server" in caplog.text and "not answering" not in caplog.text
    assert not fleet.members[0].alive()


# ---- end to end ------------------------------------------------------------------------------


@pytest.mark.slow
def test_a_second_serve_on_the_same_ports_leaves_the_first_ones_status(
    spawn: Spawn, tmp_path: Path
) -> None:
    """The tester's repro with real fleets: the second exits 2, ``status`` still shows the
    first fleet's pid, and the first marks its servers stopped when it ends."""
    base, env = free_test_ports(), {"NEURONSMAE_STATE_DIR": str(tmp_path)}
    args = ["-m", "neuronsmae.server.serving.fleet", "--base-port", str(base), "--count", "1"]
    args += ["--time-scale", "0", "--log-dir", str(tmp_path / "logs")]
    first = spawn(*args, name="first", env=env)
    first_log = tmp_path / "first-0.log"
    wait_for(lambda: "serving 1 arenas" in first_log.read_text(), 240, "the first fleet")
    state = tmp_path / f"neuronsmae-serve-{base}.json"
    before = state.read_text()

    second = subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=120, env=_env(env)
    )
    assert second.returncode == 2 and "already in use" in second.stderr, second.stderr
    assert state.read_text() == before
    status = subprocess.run(
        [sys.executable, "-m", "neuronsmae.server.serving.fleet", "status", "--base-port",
         str(base), "--json"],
        capture_output=True, text=True, timeout=120, env=_env(env),
    )  # fmt: skip
    row = json.loads(status.stdout)[0]
    assert status.returncode == 0 and row["state"] == "up"
    assert row["pid"] == json.loads(before)["servers"][0]["pid"]

    assert stop(first) == 0
    assert json.loads(state.read_text())["fleet_pid"] is None
    assert not listening(base)


def _env(extra: dict[str, str]) -> dict[str, str]:
    return {**os.environ, **extra}
