"""``deploy/run_router.py``: what a ``--config`` file leaves out takes the script's safe
defaults (loopback, no scouting), not Zenoh's (every interface, multicast on), and an
endpoint with an impossible port is a usage error."""

from __future__ import annotations

import importlib.util
import json
import socket
import subprocess
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import psutil
import pytest
import zenoh

from .conftest import ROUTER_SCRIPT, free_test_ports, wait_for

Spawn = Callable[..., subprocess.Popen[bytes]]


def _router() -> ModuleType:
    spec = importlib.util.spec_from_file_location("run_router", ROUTER_SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _json(conf: zenoh.Config, key: str) -> object:
    return json.loads(conf.get_json(key))


def _file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "router.json5"
    path.write_text(text)
    return path


def test_a_file_without_listen_or_scouting_gets_loopback_and_no_scouting(
    tmp_path: Path,
) -> None:
    router = _router()
    conf, applied = router.build_config(_file(tmp_path, '{mode: "router"}'), [])
    assert _json(conf, "listen/endpoints") == ["tcp/127.0.0.1:7447"]
    assert router.exposed(_json(conf, "listen/endpoints")) == []
    assert _json(conf, "scouting/multicast/enabled") is False
    assert _json(conf, "scouting/gossip/enabled") is False
    off = ["multicast scouting off", "gossip scouting off"]
    assert applied == [*off, "listen on tcp/127.0.0.1:7447"]
    # what Zenoh alone makes of the same file: every interface, scouting unset (on)
    bare = zenoh.Config.from_file(str(tmp_path / "router.json5"))
    assert _json(bare, "listen/endpoints")["router"] == ["tcp/[::]:7447"]  # type: ignore[index]
    assert _json(bare, "scouting/multicast/enabled") is None


def test_what_a_file_says_is_kept(tmp_path: Path) -> None:
    text = """{mode: "router", listen: {endpoints: ["tcp/[::]:7447"]},
              scouting: {multicast: {enabled: true}, gossip: {enabled: false}}}"""
    conf, applied = _router().build_config(_file(tmp_path, text), [])
    assert applied == []
    assert _json(conf, "listen/endpoints") == ["tcp/[::]:7447"]
    assert _json(conf, "scouting/multicast/enabled") is True
    assert _json(conf, "scouting/gossip/enabled") is False


def test_listen_given_on_the_command_line_is_not_replaced(tmp_path: Path) -> None:
    conf, applied = _router().build_config(_file(tmp_path, "{}"), ["tcp/127.0.0.1:28001"])
    assert _json(conf, "listen/endpoints") == ["tcp/127.0.0.1:28001"]
    assert applied == ["multicast scouting off", "gossip scouting off"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--listen", "tcp/127.0.0.1:99999"], "--listen must be a Zenoh locator tcp/<host>:<port>"),
        (["--listen", "tcp/127.0.0.1"], "with a port in 0..65535, such as tcp/10.0.0.1:7447"),
        (["--listen", "tls/:7447"], "got 'tls/:7447'"),
        (["--config", "FILE"], "router.json5: a listen endpoint must be a Zenoh locator"),
    ],
)
def test_an_impossible_port_is_a_usage_error(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--listen tcp/127.0.0.1:99999`` was accepted and failed only in ``zenoh.open``, exit 1."""
    if argv[1] == "FILE":
        text = '{mode: "router", listen: {endpoints: ["tcp/127.0.0.1:70000"]}}'
        argv = ["--config", str(_file(tmp_path, text))]
    with pytest.raises(SystemExit) as exc:
        _router().main(argv)
    assert exc.value.code == 2
    assert message in capsys.readouterr().err


@pytest.mark.slow
def test_a_router_from_a_file_without_scouting_opens_no_udp_socket(
    spawn: Spawn, tmp_path: Path
) -> None:
    """Run it: with Zenoh's default it would also hold a multicast UDP socket on
    224.0.0.224:7446 and another on 0.0.0.0."""
    port = free_test_ports()
    text = f'{{mode: "router", listen: {{endpoints: ["tcp/127.0.0.1:{port}"]}}}}'
    proc = spawn(str(ROUTER_SCRIPT), "--config", str(_file(tmp_path, text)), name="router")
    log = tmp_path / "router-0.log"
    wait_for(lambda: "run_router.py: router " in log.read_text() or proc.poll() is not None,
             30, "the router")  # fmt: skip
    assert proc.poll() is None, log.read_text()
    sockets = psutil.Process(proc.pid).net_connections("all")
    assert [(s.type, s.laddr, s.status) for s in sockets] == [
        (socket.SOCK_STREAM, ("127.0.0.1", port), psutil.CONN_LISTEN)
    ]
    text = log.read_text()
    assert "defaults, not Zenoh's: multicast scouting off, gossip scouting off" in text
    assert f"listening on tcp/127.0.0.1:{port}" in text
