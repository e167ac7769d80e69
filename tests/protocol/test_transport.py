"""The session settings' helpers: locators and Zenoh's error messages as users read them."""

from __future__ import annotations

import pytest
import zenoh

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.transport import check_locator, client_config, zenoh_message


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
