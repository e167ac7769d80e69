"""``neuronsmae-fleet``: start N servers, report them, restart a killed one, stop on SIGTERM."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path

import pytest

from neuronsmae.protocol.launch import ServerCommand
from neuronsmae.server.serving import fleet as fleet_cli
from neuronsmae.server.serving.fleet import main, read_state, status
from neuronsmae.server.serving.supervisor import Fleet, FleetSpec, FleetStartError, Member

from .conftest import free_ports, listening, server_cmd, stop, wait_for

Spawn = Callable[..., subprocess.Popen[bytes]]


def _status(base: int, count: int, state: Path) -> list[dict[str, object]]:
    return status(FleetSpec(base_port=base, count=count), state, timeout=2.0)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@pytest.mark.slow
def test_serve_restarts_a_killed_server_and_stops_on_sigterm(spawn: Spawn, tmp_path: Path) -> None:
    base, state = free_ports(2), tmp_path / "state.json"
    args = ["--base-port", str(base), "--count", "2", "--seed", "7", "--time-scale", "0"]
    args += ["--interval", "0.5", "--log-dir", str(tmp_path / "logs"), "--state-file", str(state)]
    fleet = spawn("-m", "neuronsmae.server.serving.fleet", *args, name="fleet")

    def all_up() -> bool:
        assert fleet.poll() is None, "neuronsmae-fleet exited"
        return all(r["state"] == "up" and r["pid"] for r in _status(base, 2, state))

    wait_for(all_up, 240, "both servers")
    # Answering pings is not enough: until the fleet's own start-up check has seen both
    # servers, a server that dies is a start-up failure (the fleet exits with an error, by
    # design), not a crash to restart. Supervision begins with this log line.
    fleet_log = tmp_path / "fleet-0.log"
    wait_for(lambda: "serving 2 arenas" in fleet_log.read_text(), 60, "supervision to begin")
    before = _status(base, 2, state)
    assert [r["port"] for r in before] == [base, base + 1]
    recorded = json.loads(state.read_text())
    assert [s["seed"] for s in recorded["servers"]] == [7, 8]

    victim = before[1]
    os.kill(int(victim["pid"]), signal.SIGKILL)  # type: ignore[call-overload]

    def replaced() -> bool:
        row = _status(base, 2, state)[1]
        return row["state"] == "up" and row["pid"] not in (None, victim["pid"])

    wait_for(replaced, 180, "the killed server to be restarted")
    after = _status(base, 2, state)
    assert after[1]["server"] != victim["server"] and after[1]["starts"] == 2
    assert after[0]["pid"] == before[0]["pid"]  # the other one was left alone

    assert stop(fleet) == 0
    pids = [int(r["pid"]) for r in after]  # type: ignore[call-overload]
    assert not any(_alive(pid) for pid in pids)
    assert not listening(base) and not listening(base + 1)
    assert all(r["state"] == "down" and r["pid"] is None for r in _status(base, 2, state))


@pytest.mark.slow
def test_taken_port_fails_fast(spawn: Spawn, tmp_path: Path) -> None:
    base = free_ports()
    squatter = spawn(*server_cmd(base), name="squatter")
    wait_for(lambda: _status(base, 1, tmp_path / "none.json")[0]["state"] == "up", 180, "squat")
    fleet = Fleet(FleetSpec(base_port=base, count=1), tmp_path / "logs", tmp_path / "s.json")
    with fleet, pytest.raises(FleetStartError, match="in use"):
        fleet.start(timeout=120)
    assert squatter.poll() is None


def test_dead_server_restarts_later_each_time(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Backoff without real servers: a 'server' that exits at once is restarted 0.5 s, then
    1 s, then 2 s after each death."""
    fleet = Fleet(FleetSpec(base_port=free_ports()), tmp_path / "logs", tmp_path / "s.json")

    class Crash(ServerCommand):  # started the same way as a server, but exits at once
        def argv(self) -> list[str]:
            return [sys.executable, "-c", "import sys; sys.exit(3)"]

    monkeypatch.setattr(fleet, "command", lambda member: Crash(member.port))
    clock = [1000.0]
    monkeypatch.setattr("neuronsmae.server.serving.supervisor.time.monotonic", lambda: clock[0])
    member: Member = fleet.members[0]
    with fleet:
        fleet._spawn(member)
        delays = []
        for _ in range(3):
            member.proc.wait()  # type: ignore[union-attr]
            health = fleet.check()[0]
            assert not health.up and "status 3" in health.error
            assert member.restart_at is not None
            delays.append(member.restart_at - clock[0])
            clock[0] = member.restart_at
            fleet.check()  # due: started again
        assert delays == [0.5, 1.0, 2.0]
        assert member.starts == 4 and fleet.restarts == 3
    assert "start 4 of the server" in (tmp_path / "logs" / f"server-{member.port}.log").read_text()


def test_status_of_nothing_is_down_and_exits_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = free_ports(2)
    code = main(["status", "--base-port", str(base), "--count", "2", "--json",
                 "--state-file", str(tmp_path / "absent.json")])  # fmt: skip
    rows = json.loads(capsys.readouterr().out)
    assert code == 1 and [r["state"] for r in rows] == ["down", "down"]
    assert "no server listens" in rows[0]["error"]


def test_bad_count_is_a_usage_error() -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--count", "0"])
    assert exc.value.code == 2


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--seed", "-1"], "seed must be an integer in [0, 9223372036854775807]"),
        (["--seed", str(2**63 - 3), "--count", "2", "--arenas", "2"], "passes the largest seed"),
        (["--lease", "nan"], "lease must be a finite number of seconds > 0, got nan"),
        (["--time-scale", "-2"], "time_scale must be a finite number >= 0"),
        (["--arenas", "65"], "arenas must be an integer in [1, 64], got 65"),
        (["--router", "10.0.0.1:7447"], "router must be a Zenoh locator <protocol>/<address>"),
        (["--router", "tcp/127.0.0.1:99999"], "--router must be a Zenoh locator tcp/<host>:<port>"),
        (["--interval", "0"], "interval must be a finite number of seconds >= 0.1, got 0.0"),
        (["--interval", "nan"], "interval must be a finite number of seconds >= 0.1, got nan"),
        (["--ping-timeout", "0"], "--ping-timeout must be a finite number of seconds > 0"),
        (["--ping-timeout", "nan"], "--ping-timeout must be a finite number of seconds > 0"),
        (["--host", "192.0.2.1"], "--host '192.0.2.1' is not an address of this machine"),
        (["--host", ""], "--host must be an address of this machine"),
    ],
)
def test_bad_server_settings_are_usage_errors_before_any_server_starts(
    argv: list[str],
    message: str,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def no_fleet(*args: object, **kwargs: object) -> None:
        raise AssertionError("a fleet was started")

    monkeypatch.setattr(fleet_cli, "Fleet", no_fleet)
    with pytest.raises(SystemExit) as exc:
        main(["--base-port", str(free_ports()), *argv])
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("text", ["{not json", "[1, 2]", '{"servers": 3}', '"x"'])
def test_an_unreadable_state_file_counts_as_no_fleet(
    text: str, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    state = tmp_path / "state.json"
    state.write_text(text)
    with caplog.at_level("WARNING", logger="neuronsmae.serve"):
        assert read_state(state) == {}
    assert "ignoring" in caplog.text and str(state) in caplog.text
    assert read_state(tmp_path / "absent.json") == {}


def test_bad_ports_name_both_flags(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["status", "--base-port", "65535", "--count", "3"])
    assert exc.value.code == 2
    assert "--base-port 65535 --count 3" in capsys.readouterr().err


def test_bad_supervision_settings_are_refused_before_any_server_starts(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--base-port", str(free_ports()), "--max-missed", "-1"])
    assert exc.value.code == 2
    assert "max_missed must be an integer >= 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        main(["status", "--ping-timeout", "nan"])
    assert exc.value.code == 2
    assert "--ping-timeout must be a finite number of seconds > 0" in capsys.readouterr().err
    a_file = tmp_path / "logs"
    a_file.write_text("not a folder")
    state = tmp_path / "state.json"
    argv = ["--base-port", str(free_ports()), "--log-dir", str(a_file), "--state-file", str(state)]
    assert main(argv) == 2
    assert not state.exists()  # nothing was started
    with pytest.raises(FleetStartError, match="cannot be a folder for the servers' logs"):
        Fleet(FleetSpec(base_port=free_ports()), a_file).__enter__()


def _script(name: str) -> str:
    """The installed console script ``name`` (beside this Python first)."""
    found = shutil.which(name, path=str(Path(sys.executable).parent)) or shutil.which(name)
    if found is None:
        pytest.fail(f"no {name} script: run `pip install -e . --no-deps`")
    return found


def test_the_fleet_command_is_neuronsmae_fleet_and_neuronsmae_serve_its_deprecated_alias() -> None:
    scripts = {e.name: e.value for e in entry_points(group="console_scripts")}
    assert scripts["neuronsmae-fleet"] == "neuronsmae.server.serving.fleet:main"
    assert scripts["neuronsmae-serve"] == "neuronsmae.server.serving.fleet:deprecated_main"
    assert scripts["neuronsmae-server"] == "neuronsmae.server.serving.cli:main"


@pytest.mark.slow
def test_both_fleet_names_run_and_only_the_old_one_warns(tmp_path: Path) -> None:
    base = free_ports()
    status = ["status", "--base-port", str(base), "--ping-timeout", "0.5", "--json"]
    status += ["--state-file", str(tmp_path / "state.json")]
    for name in ("neuronsmae-fleet", "neuronsmae-serve"):
        shown = subprocess.run([_script(name), "--help"], capture_output=True, text=True)
        assert shown.returncode == 0 and shown.stdout.startswith("usage: neuronsmae-fleet ")
        ran = subprocess.run([_script(name), *status], capture_output=True, text=True)
        assert ran.returncode == 1, ran.stderr  # nothing listens there: down, exit 1
        assert [r["state"] for r in json.loads(ran.stdout)] == ["down"]
        for out in (shown, ran):
            notes = [line for line in out.stderr.splitlines() if "deprecated" in line]
            if name == "neuronsmae-fleet":
                assert notes == [], out.stderr
            else:
                assert notes == [
                    "neuronsmae-serve is deprecated and will be removed: use neuronsmae-fleet "
                    "(the same command)"
                ]
