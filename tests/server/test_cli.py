"""``neuronsmae-server``'s arguments: each bad one is refused before anything starts, with a
message that names it and what is valid."""

from __future__ import annotations

import logging

import pytest

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.server.serving import cli
from neuronsmae.server.serving.locators import check_endpoint


def test_defaults_are_valid() -> None:
    assert cli.invalid_arguments(cli._parser().parse_args([])) == []


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--port", "0"], "--port must be in 1..65535, got 0"),
        (["--port", "65536"], "--port must be in 1..65535, got 65536"),
        (
            ["--seed", "-1"],
            "--seed must be in 0..9223372036854775807 (arena i is seeded seed + i), got -1",
        ),
        (["--seed", str(2**63)], "--seed must be in 0..9223372036854775807"),
        (["--seed", str(2**63 - 2), "--arenas", "4"], "--seed must be in 0..9223372036854775804"),
        (["--arenas", "0"], "--arenas must be in 1..64, got 0"),
        (["--arenas", "65"], "--arenas must be in 1..64, got 65"),
        (["--time-scale", "-1"], "--time-scale must be a finite number >= 0, got -1"),
        (["--time-scale", "nan"], "--time-scale must be a finite number >= 0, got nan"),
        (["--lease", "0"], "--lease must be a finite number of seconds > 0, got 0"),
        (["--lease", "inf"], "--lease must be a finite number of seconds > 0, got inf"),
        (["--busy-poll", "-5"], "--busy-poll must be in 0..100000 microseconds, got -5"),
        (
            ["--router", "tcp/h:7447", "--router", "h:7447"],
            "--router must be a Zenoh locator <protocol>/<address> such as tcp/10.0.0.1:7447, "
            "got 'h:7447'",
        ),
        (
            ["--router", "tcp/127.0.0.1:99999"],
            "--router must be a Zenoh locator tcp/<host>:<port> with a port in 1..65535, such "
            "as tcp/10.0.0.1:7447, got 'tcp/127.0.0.1:99999'",
        ),
        (["--router", "tcp/127.0.0.1:0"], "with a port in 1..65535"),
        (["--router", "tls/10.0.0.1"], "--router must be a Zenoh locator tls/<host>:<port>"),
        (["--router", "tcp/:7447"], "got 'tcp/:7447'"),
        (["--router", "udp/h:x"], "got 'udp/h:x'"),
        (["--host", ""], "--host must be an address of this machine such as 127.0.0.1"),
        (["--host", "nohost.invalid"], "--host 'nohost.invalid' does not resolve"),
        (["--host", "192.0.2.1"], "--host '192.0.2.1' is not an address of this machine"),
    ],
)
def test_bad_argument_is_refused_by_name(
    argv: list[str], message: str, caplog: pytest.LogCaptureFixture
) -> None:
    with caplog.at_level(logging.ERROR, logger="neuronsmae.server"):
        assert cli.run(argv) == 2
    assert any(message in r.getMessage() for r in caplog.records), caplog.text


def test_every_problem_is_reported_at_once() -> None:
    args = cli._parser().parse_args(["--port", "0", "--arenas", "99", "--lease", "-1"])
    problems = cli.invalid_arguments(args)
    assert [p.split()[0] for p in problems] == ["--port", "--arenas", "--lease"]


@pytest.mark.parametrize(
    "locator",
    [
        "tcp/10.0.0.1:7447",
        "tcp/[::1]:7447",
        "tls/router.lan:7447",
        "tcp/127.0.0.1:7447#iface=lo",
        "quic/h:65535",
        "unixsock-stream/tmp/zenoh.sock",
    ],
)
def test_a_valid_router_is_accepted(locator: str) -> None:
    check_endpoint(locator, "--router")
    assert cli.invalid_arguments(cli._parser().parse_args(["--router", locator])) == []


def test_port_0_is_for_listening_only() -> None:
    check_endpoint("tcp/127.0.0.1:0", "--listen", listen=True)
    with pytest.raises(InvalidOptionError, match=r"--listen must .* port in 0\.\.65535"):
        check_endpoint("tcp/127.0.0.1:65536", "--listen", listen=True)
    with pytest.raises(InvalidOptionError, match=r"router must .* port in 1\.\.65535"):
        check_endpoint("tcp/127.0.0.1:0")
