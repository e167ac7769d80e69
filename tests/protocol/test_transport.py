"""The session settings' helpers: locators and Zenoh's error messages as users read them."""

from __future__ import annotations

import pytest
import zenoh

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.transport import check_host, check_locator, client_config, zenoh_message


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
