"""The session settings' helpers: locators, the TLS file and Zenoh's error messages as users
read them."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.launch import ServerCommand, ServerProcess
from neuronsmae.protocol.link import Link
from neuronsmae.protocol.transport import (
    TLS_ENV,
    check_host,
    check_locator,
    client_config,
    server_config,
    zenoh_message,
)


def test_a_zenoh_error_reads_on_one_line_without_its_rust_source_path() -> None:
    with pytest.raises(zenoh.ZError) as caught:
        zenoh.Config.from_file("/nonexistent/zenoh.json5")
    assert "/.cargo/" in str(caught.value) or " at /" in str(caught.value)  # what Zenoh says
    message = zenoh_message(caught.value)
    assert message and "\n" not in message and " at /" not in message
    assert zenoh_message(ValueError("a\n  b at /x/y.rs:1")) == "a b"


@pytest.mark.parametrize("router", ["tcp/10.0.0.1:7447", "tls/host:7447", "udp/[::1]:7447"])
def test_a_locator_passes_and_configures_a_client(router: str) -> None:
    check_locator(router)
    assert isinstance(client_config("127.0.0.1", 10000, router), zenoh.Config)


@pytest.mark.parametrize("router", ["", "10.0.0.1:7447", "tcp/", "TCP/x", 7447, None])
def test_anything_else_is_refused_naming_the_form(router: object) -> None:
    with pytest.raises(InvalidOptionError, match=r"router must be a Zenoh locator <protocol>/"):
        check_locator(router)


@pytest.mark.parametrize("host", ["", "a b", None, 3, ["127.0.0.1"]])
def test_a_client_refuses_a_host_that_is_no_name_or_address(host: object) -> None:
    """'' made the locator tcp/:port; None or a number was a TypeError in the client."""
    from neuronsmae.client import RM, VecRM

    with pytest.raises(InvalidOptionError, match="host must be a host name or address"):
        check_host(host)
    for client in (RM, VecRM):
        with pytest.raises(InvalidOptionError, match="host must be a host name or address"):
            client(port=10000, host=host, launch=False, timeout=1)
    for good in ("127.0.0.1", "server.lan", "::1", "[::1]"):
        check_host(good)


# ---- NEURONSMAE_ZENOH_TLS -------------------------------------------------------------------

TLS = {"root_ca_certificate": "/pki/ca.pem", "connect_certificate": "/pki/me.pem",
       "connect_private_key": "/pki/me.key", "enable_mtls": True}  # fmt: skip


def _bad_tls_files(tmp: Path) -> dict[str, tuple[Path, str]]:
    """Files NEURONSMAE_ZENOH_TLS may wrongly name, and what the refusal says of each."""
    (tmp / "invalid.json5").write_text("{ transport: ")
    (tmp / "wrong-type.json5").write_text(
        json.dumps({"transport": {"link": {"tls": {"enable_mtls": "yes"}}}})
    )
    (tmp / "no-tls.json5").write_text(json.dumps({"mode": "client"}))
    (tmp / "tls.txt").write_text(json.dumps({"transport": {"link": {"tls": TLS}}}))
    return {
        "missing": (tmp / "nope.json5", "cannot be read (No such file or directory)"),
        "directory": (tmp, "cannot be read (Is a directory)"),
        "invalid": (tmp / "invalid.json5", "is not a valid Zenoh configuration"),
        "wrong-type": (tmp / "wrong-type.json5", "is not a valid Zenoh configuration"),
        "no-tls": (tmp / "no-tls.json5", "sets nothing under transport.link.tls"),
        "not-json5": (tmp / "tls.txt", "is not a valid Zenoh configuration (Unsupported file type"),
    }


BAD_TLS = ["missing", "directory", "invalid", "wrong-type", "no-tls", "not-json5"]


@pytest.mark.parametrize("case", BAD_TLS)
def test_an_unusable_tls_file_is_refused_naming_the_variable_and_the_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, case: str
) -> None:
    """A missing file was Zenoh's bare "No such file or directory (os error 2)", which a
    client's Link took for "no server listens" (and the server it then launched died of)."""
    path, said = _bad_tls_files(tmp_path)[case]
    monkeypatch.setenv(TLS_ENV, str(path))
    expected = f"^{re.escape(f'{TLS_ENV}={str(path)!r} {said}')}.*it must name a readable Zenoh"
    for build in (client_config, server_config):
        with pytest.raises(InvalidOptionError, match=expected):
            build("127.0.0.1", 29001)
    link = Link("127.0.0.1", 29001)
    with pytest.raises(InvalidOptionError, match=TLS_ENV):  # not False: "nothing listens"
        link.open()
    with pytest.raises(InvalidOptionError, match=TLS_ENV):  # not ServerUnavailableError
        link.call(b"", 1.0)
    link.close()


def test_a_usable_tls_file_reaches_every_session_and_an_empty_variable_means_none(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "tls.json5"
    path.write_text(json.dumps({"transport": {"link": {"tls": TLS}}, "mode": "router"}))
    monkeypatch.setenv(TLS_ENV, str(path))
    for conf in (client_config("127.0.0.1", 29001), server_config("127.0.0.1", 29001)):
        tls = json.loads(conf.get_json("transport/link/tls"))
        assert {key: tls[key] for key in TLS} == TLS
        assert json.loads(conf.get_json("mode")) != "router"  # only the TLS section is used
    monkeypatch.setenv(TLS_ENV, "")
    assert json.loads(
        client_config("127.0.0.1", 29001).get_json("transport/link/tls")
    ) == json.loads(zenoh.Config().get_json("transport/link/tls"))


def test_a_bad_tls_file_is_refused_before_a_server_is_launched(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Clients (private or on a free port, launching or not) and ServerProcess (the trainers'
    launcher) refuse it first; the server they would have started could only exit."""
    from neuronsmae.client import RM, VecRM, answering_pid, ping

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("a server was launched")

    monkeypatch.setattr("neuronsmae.protocol.launch.subprocess.Popen", refuse)
    path = tmp_path / "nope.json5"
    monkeypatch.setenv(TLS_ENV, str(path))
    said = re.escape(f"{TLS_ENV}='{path}' cannot be read")
    with pytest.raises(InvalidOptionError, match=said):
        ServerProcess(ServerCommand(29002))
    for kwargs in ({}, {"port": 29002}, {"port": 29002, "launch": False}):
        for client in (RM, VecRM):
            with pytest.raises(InvalidOptionError, match=said):
                client(**kwargs)
    for query in (ping, answering_pid):  # not "no server answers" (ping) or None (the pid)
        with pytest.raises(InvalidOptionError, match=said):
            query(29002)


@pytest.mark.slow
def test_a_server_given_a_bad_tls_file_exits_saying_so(tmp_path: Path) -> None:
    """The server reads the variable through the same protocol code: it exits at once with
    status 1, its log naming the variable and the file (was "cannot start: No such file or
    directory (os error 2)")."""
    path = tmp_path / "nope.json5"
    run = subprocess.run(
        [sys.executable, "-m", "neuronsmae.server", "--port", "29003", "--time-scale", "0"],
        env={**os.environ, TLS_ENV: str(path)},
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 1, run.stderr
    assert f"cannot start: {TLS_ENV}='{path}' cannot be read (No such file" in run.stderr
