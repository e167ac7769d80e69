"""Who can reach what: loopback by default, and a warning for anything wider.

The protocol identifies clients but does not authenticate them, so the defence is where
servers and the router listen: only on loopback unless told otherwise, and a warning when
told otherwise. TLS and access control for the router are in ``test_tls.py``.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import psutil
import pytest
import zenoh

from neuronsmae.protocol.transport import client_config, server_config
from neuronsmae.server.serving import cli

from .conftest import Server, free_port

REPO = Path(__file__).resolve().parents[2]
DEPLOY = REPO / "deploy"


def _json(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def test_server_and_client_configs_name_one_loopback_endpoint() -> None:
    conf = server_config("127.0.0.1", 10007)
    assert _json(conf, "listen/endpoints") == ["tcp/127.0.0.1:10007"]
    assert _json(conf, "connect/endpoints") == []
    assert _json(conf, "scouting/multicast/enabled") is False
    assert _json(conf, "scouting/gossip/enabled") is False
    client = client_config("127.0.0.1", 10007)
    assert _json(client, "listen/endpoints") == []
    assert _json(client, "connect/endpoints") == ["tcp/127.0.0.1:10007"]
    assert cli._parser().parse_args([]).host == "127.0.0.1"


def test_a_running_server_listens_on_its_loopback_port_only(
    start_server: Callable[..., Server],
) -> None:
    server = start_server()
    sockets = psutil.Process(server.proc.pid).net_connections(kind="inet")
    listening = {(c.laddr.ip, c.laddr.port) for c in sockets if c.status == psutil.CONN_LISTEN}
    assert listening == {("127.0.0.1", server.port)}
    udp = [c.laddr for c in sockets if c.type == socket.SOCK_DGRAM]
    assert udp == []  # no multicast scouting socket


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.2", "::1", "[::1]", "localhost"])
def test_loopback_hosts_are_not_warned_about(host: str) -> None:
    assert cli.exposure_warning(host, 10000) is None


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "10.0.0.5", "192.168.1.2", "arena.lan"])
def test_other_hosts_are_warned_about(host: str) -> None:
    warning = cli.exposure_warning(host, 10000)
    assert warning is not None and "not on loopback" in warning and host in warning


def test_the_server_cli_logs_the_warning(caplog: pytest.LogCaptureFixture) -> None:
    """A server asked for 0.0.0.0 warns before anything else (here its port is taken, so
    it stops right after, without building an arena)."""
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        with socket.socket() as taken:
            taken.bind(("0.0.0.0", 0))
            taken.listen()
            port = taken.getsockname()[1]
            with caplog.at_level(logging.WARNING, logger="neuronsmae.server"):
                assert cli.run(["--host", "0.0.0.0", "--port", str(port)]) == 2
                assert cli.run(["--host", "127.0.0.1", "--port", str(port)]) == 2
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1 and f"0.0.0.0:{port}, not on loopback" in warnings[0]


# ---- the router ----------------------------------------------------------------------------


def _router_module() -> ModuleType:
    spec = importlib.util.spec_from_file_location("run_router", DEPLOY / "run_router.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--listen", "7447"], "--listen must be a Zenoh locator <protocol>/<address>"),
        (["--config", "/nonexistent.json5"], "--config /nonexistent.json5: no such file"),
        (["--config", "{bad}"], "not a usable Zenoh configuration: --> 1:1"),
    ],
)
def test_router_refuses_bad_arguments_by_name(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """These were Zenoh's tracebacks, ending in a path into its Rust sources."""
    if argv[1] == "{bad}":
        bad = tmp_path / "bad.json5"
        bad.write_text("{broken")
        argv = ["--config", str(bad)]
    with pytest.raises(SystemExit) as exit_:
        _router_module().main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert message in err and ".cargo" not in err


def test_router_listens_on_loopback_by_default() -> None:
    router = _router_module()
    for config in (None, router.CONFIG):
        conf = router.router_config(config, [])
        endpoints = _json(conf, "listen/endpoints")
        assert endpoints == ["tcp/127.0.0.1:7447"], config
        assert router.exposed(endpoints) == []
        assert _json(conf, "scouting/multicast/enabled") is False


def test_router_exposure_rules() -> None:
    exposed = _router_module().exposed
    assert exposed(["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tls/localhost:7447"]) == []
    wide = ["tcp/0.0.0.0:7447", "tcp/10.0.0.1:7447", "tls/0.0.0.0:7447", "tcp/[::]:7447"]
    assert exposed(wide) == wide
    assert exposed(wide, mtls=True) == [ep for ep in wide if not ep.startswith("tls/")]


@pytest.mark.parametrize("name", ["zenoh-router-tls.json5", "zenoh-router-acl.json5"])
def test_tls_router_configs_require_client_certificates(name: str) -> None:
    conf = zenoh.Config.from_file(str(DEPLOY / name))
    assert _json(conf, "mode") == "router"
    assert _json(conf, "transport/link/protocols") == ["tls"]
    assert _json(conf, "transport/link/tls/enable_mtls") is True
    assert all(ep.startswith("tls/127.0.0.1:") for ep in _json(conf, "listen/endpoints"))
    if "acl" in name:
        assert _json(conf, "access_control/enabled") is True
        assert _json(conf, "access_control/default_permission") == "deny"


@pytest.mark.slow
def test_router_warns_when_it_listens_beyond_loopback(tmp_path: Path) -> None:
    log = tmp_path / "router.log"
    port = free_port()
    cmd = [sys.executable, str(DEPLOY / "run_router.py"), "--listen", f"tcp/0.0.0.0:{port}"]
    with log.open("wb") as out:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=out, stderr=out)
    try:
        deadline = time.monotonic() + 30
        while "run_router.py: router " not in log.read_text():  # its session is open
            assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
    finally:
        proc.terminate()
        proc.wait(10)
    text = log.read_text()
    assert f"WARNING: listening on tcp/0.0.0.0:{port}, not on loopback" in text
