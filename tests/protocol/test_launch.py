"""A launched server's log: it has no name in the temporary directory, so however its client
ends (``close()``, SIGKILL, ``os._exit``) nothing is left behind, and it still tells why a
server that failed to start did."""

from __future__ import annotations

import glob
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import pytest

from neuronsmae.protocol.errors import ServerUnavailableError
from neuronsmae.protocol.launch import ServerCommand, ServerProcess


def named_logs(port: int) -> list[str]:
    """Log files of servers launched for ``port`` that have a name in the temp directory
    (where the launcher's named logs used to pile up: one per SIGKILLed client)."""
    return glob.glob(os.path.join(tempfile.gettempdir(), f"neuronsmae-server-{port}-*"))


def scripted(port: int, code: str) -> ServerCommand:
    """A command started exactly as a server is (``ServerCommand.spawn``), running ``code``."""

    class Scripted(ServerCommand):
        def argv(self) -> list[str]:
            return [sys.executable, "-c", code]

    return Scripted(port)


def test_a_server_that_fails_to_start_is_reported_with_its_output() -> None:
    server = ServerProcess(scripted(29010, "import sys; print('cannot start: boom'); sys.exit(1)"))
    try:
        assert named_logs(29010) == []
        with pytest.raises(
            ServerUnavailableError, match="exited with status 1:\ncannot start: boom"
        ):
            server.wait_ready(lambda: None, timeout=30)
    finally:
        server.stop()
    assert server.log_tail() == "" and named_logs(29010) == []
    server.stop()  # twice is fine


def test_the_log_is_unnamed_and_reading_it_leaves_the_server_writing(tmp_path: Path) -> None:
    """The server's stdout shares the launcher's file offset: the tail is read with pread,
    so reading it in between does not make the server write over its own log."""
    go = tmp_path / "go"
    code = (
        "import os, sys, time\n"
        "print('first', flush=True)\n"
        f"while not os.path.exists({str(go)!r}): time.sleep(0.01)\n"
        "print('second', file=sys.stderr, flush=True)\n"
    )
    server = ServerProcess(scripted(29011, code))
    try:
        deadline = time.monotonic() + 30
        while server.log_tail() != "first":
            assert time.monotonic() < deadline, server.log_tail()
            time.sleep(0.01)
        assert named_logs(29011) == []
        for fd in (1, 2):  # the server writes to a file without a name
            assert os.readlink(f"/proc/{server.proc.pid}/fd/{fd}").endswith(" (deleted)")
        go.touch()
        assert server.proc.wait(30) == 0
        assert server.log_tail() == "first\nsecond"
        assert server.log_tail(limit=7) == "second"
    finally:
        server.stop()
    assert server.log_tail() == ""


CLIENT = """
import os, sys
from neuronsmae.client import RM
env = RM(time_scale=0)  # a private server on a free port
print(env.port, env._conn.server.proc.pid, flush=True)
if sys.stdin.readline().strip() == "exit":
    os._exit(0)  # no close(), no finalizers
sys.stdin.read()  # wait to be killed
"""


@pytest.mark.slow
@pytest.mark.parametrize("death", ["SIGKILL", "os._exit"])
def test_a_killed_client_leaves_no_server_log_behind(death: str) -> None:
    """Each client killed with SIGKILL (as Ray kills its workers) or leaving through
    ``os._exit`` left its private server's ``/tmp/neuronsmae-server-<port>-*.log``."""
    with subprocess.Popen(  # leaving closes the pipes and waits
        [sys.executable, "-c", CLIENT],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    ) as client:
        try:
            port, server_pid = map(int, client.stdout.readline().split())  # type: ignore[union-attr]
            assert named_logs(port) == []
            assert os.readlink(f"/proc/{server_pid}/fd/2").endswith(" (deleted)")
        finally:
            if death == "SIGKILL":
                client.kill()
            else:
                client.stdin.write("exit\n")  # type: ignore[union-attr]
                client.stdin.flush()  # type: ignore[union-attr]
        assert client.wait(30) == (-9 if death == "SIGKILL" else 0)
    deadline = time.monotonic() + 10.0
    while _alive(server_pid):  # the server notices its parent is gone and exits
        assert time.monotonic() < deadline, "the launched server outlived its client"
        time.sleep(0.05)
    assert named_logs(port) == []


def _alive(pid: int) -> bool:
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return False
