"""The TLS router configurations refuse whoever lacks a certificate from their CA.

A throwaway CA and certificates are made per module (``pki.py``); the router is the real
``deploy/zenoh-router-tls.json5`` / ``deploy/zenoh-router-acl.json5`` with only the
certificate paths and the port replaced, on loopback. The last test runs a real
``neuronsmae-server`` and ``RM`` through the ACL router with ``NEURONSMAE_ZENOH_TLS``.
"""

from __future__ import annotations

import contextlib
import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import zenoh

from neuronsmae.client import RM
from neuronsmae.protocol.errors import ServerUnavailableError
from neuronsmae.protocol.transport import TLS_ENV
from neuronsmae.server.arena import Arena

from .conftest import Server, free_port, same
from .pki import CertificateAuthority, Identity

DEPLOY = Path(__file__).resolve().parents[2] / "deploy"
KEY = "neuronsmae/1/rpc"


@dataclass(frozen=True)
class Pki:
    ca: Path
    router: Identity
    server: Identity
    client: Identity
    monitor: Identity
    """Signed by the right CA, but a common name the ACL grants nothing."""
    rogue: Identity
    """Named like the client, signed by another CA."""


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    root = tmp_path_factory.mktemp("pki")
    ca = CertificateAuthority(root / "ca")
    rogue = CertificateAuthority(root / "rogue", cn="rogue-ca")
    return Pki(
        ca=ca.cert,
        router=ca.issue("neuronsmae-router"),
        server=ca.issue("neuronsmae-server"),
        client=ca.issue("neuronsmae-client"),
        monitor=ca.issue("neuronsmae-monitor"),
        rogue=rogue.issue("neuronsmae-client"),
    )


def _set(conf: zenoh.Config, key: str, value: object) -> None:
    conf.insert_json5(key, json.dumps(value))


def _router(name: str, pki: Pki) -> tuple[zenoh.Session, str]:
    """The deploy/ configuration ``name`` with test certificates, on a free loopback port."""
    conf = zenoh.Config.from_file(str(DEPLOY / name))
    endpoint = f"tls/127.0.0.1:{free_port()}"
    _set(conf, "listen/endpoints", [endpoint])
    tls = {
        "root_ca_certificate": pki.ca,
        "listen_certificate": pki.router.cert,
        "listen_private_key": pki.router.key,
        "connect_certificate": pki.router.cert,
        "connect_private_key": pki.router.key,
    }
    for key, path in tls.items():
        _set(conf, f"transport/link/tls/{key}", str(path))
    return zenoh.open(conf), endpoint


def _session(mode: str, endpoint: str, who: Identity | None, ca: Path | None) -> zenoh.Session:
    """A session that connects to ``endpoint`` only, showing ``who``'s certificate."""
    conf = zenoh.Config()
    _set(conf, "mode", mode)
    _set(conf, "scouting/multicast/enabled", False)
    _set(conf, "scouting/gossip/enabled", False)
    _set(conf, "listen/endpoints", [])
    _set(conf, "connect/endpoints", [endpoint])
    if ca is not None:
        _set(conf, "transport/link/tls/root_ca_certificate", str(ca))
    if who is not None:
        _set(conf, "transport/link/tls/connect_certificate", str(who.cert))
        _set(conf, "transport/link/tls/connect_private_key", str(who.key))
        _set(conf, "transport/link/tls/enable_mtls", True)
    return zenoh.open(conf)


@contextlib.contextmanager
def _behind_router(name: str, pki: Pki) -> Iterator[str]:
    """A TLS router from ``name`` and, behind it, a server peer answering ``pong`` on KEY."""
    router, endpoint = _router(name, pki)
    server = _session("peer", endpoint, pki.server, pki.ca)
    queryable = server.declare_queryable(KEY, lambda query: query.reply(KEY, b"pong"))
    try:
        yield endpoint
    finally:
        queryable.undeclare()
        server.close()
        router.close()


@pytest.fixture(params=["zenoh-router-tls.json5", "zenoh-router-acl.json5"], scope="module")
def routed(request: pytest.FixtureRequest, pki: Pki) -> Iterator[str]:
    with _behind_router(request.param, pki) as endpoint:
        yield endpoint


def _ask(session: zenoh.Session, key: str = KEY) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in session.get(key, timeout=3.0) if r.ok is not None]


def _wait_for_route(endpoint: str, pki: Pki) -> None:
    """The server peer's queryable reaches the router a moment after it connects."""
    client = _session("client", endpoint, pki.client, pki.ca)
    try:
        for _ in range(100):
            if _ask(client) == [b"pong"]:
                return
            time.sleep(0.1)
        pytest.fail("the server behind the router never answered")
    finally:
        client.close()


def test_client_with_a_certificate_from_the_ca_gets_its_reply(routed: str, pki: Pki) -> None:
    endpoint = routed
    _wait_for_route(endpoint, pki)
    client = _session("client", endpoint, pki.client, pki.ca)
    try:
        assert _ask(client) == [b"pong"]
    finally:
        client.close()


REFUSED: dict[str, Callable[[Pki], tuple[Identity | None, Path | None, str]]] = {
    "no-certificate": lambda p: (None, p.ca, "tls"),
    "certificate-from-another-ca": lambda p: (p.rogue, p.ca, "tls"),
    "cannot-verify-the-router": lambda p: (p.client, None, "tls"),
    "plain-tcp": lambda p: (None, None, "tcp"),
}


@pytest.mark.parametrize("case", REFUSED, ids=list(REFUSED))
def test_client_without_the_right_certificate_is_refused(routed: str, pki: Pki, case: str) -> None:
    endpoint = routed
    who, ca, proto = REFUSED[case](pki)
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        _session("client", endpoint.replace("tls/", f"{proto}/"), who, ca)


@pytest.mark.slow
def test_acl_gives_an_unlisted_certificate_nothing(pki: Pki) -> None:
    with _behind_router("zenoh-router-acl.json5", pki) as endpoint:
        _wait_for_route(endpoint, pki)
        monitor = _session("client", endpoint, pki.monitor, pki.ca)  # the handshake succeeds
        try:
            assert _ask(monitor) == []  # ...but its queries are dropped
        finally:
            monitor.close()
        assert not _impostor_heard(endpoint, pki, tries=3)  # nor may it pose as a server
        client = _session("client", endpoint, pki.client, pki.ca)
        try:
            assert _ask(client) == [b"pong"]  # the real server still answers
        finally:
            client.close()


@pytest.mark.slow
def test_without_the_acl_the_same_certificate_can_pose_as_a_server(pki: Pki) -> None:
    """The ACL test's control: on the router without ACL the impostor is heard, and soon,
    so its silence behind the ACL is the ACL's doing and not a route still on its way."""
    with _behind_router("zenoh-router-tls.json5", pki) as endpoint:
        _wait_for_route(endpoint, pki)
        assert _impostor_heard(endpoint, pki, tries=30)


def _impostor_heard(endpoint: str, pki: Pki, tries: int) -> bool:
    """Whether a queryable the monitor identity declares on another server's key answers a
    client within ``tries`` asks (each waits at most 3 s for replies)."""
    monitor = _session("client", endpoint, pki.monitor, pki.ca)
    client = _session("client", endpoint, pki.client, pki.ca)
    key = "neuronsmae/2/rpc"
    impostor = monitor.declare_queryable(key, lambda q: q.reply(key, b"!"))
    try:
        for _ in range(tries):
            if _ask(client, key) == [b"!"]:
                return True
            time.sleep(0.1)
        return False
    finally:
        impostor.undeclare()
        monitor.close()
        client.close()


def _tls_file(path: Path, who: Identity, ca: Path) -> Path:
    tls = {
        "root_ca_certificate": str(ca),
        "connect_certificate": str(who.cert),
        "connect_private_key": str(who.key),
        "enable_mtls": True,
    }
    path.write_text(json.dumps({"transport": {"link": {"tls": tls}}}))
    return path


def _rm_through(endpoint: str, port: int, patience: float = 30.0) -> RM:
    """An RM to ``port`` via the router, once the server's link to the router is up (its
    peer session connects in the background, after the server already answers directly)."""
    deadline = time.monotonic() + patience
    while True:
        try:
            return RM(seed=5, port=port, router=endpoint, timeout=5.0)
        except ServerUnavailableError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


@pytest.mark.slow
def test_real_server_and_client_through_the_acl_router(
    pki: Pki, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    router, endpoint = _router("zenoh-router-acl.json5", pki)
    try:
        monkeypatch.setenv(TLS_ENV, str(_tls_file(tmp_path / "server.json5", pki.server, pki.ca)))
        server = Server(free_port(), "--time-scale", "0", "--router", endpoint).wait_ready()
        try:
            monkeypatch.setenv(TLS_ENV, str(_tls_file(tmp_path / "c.json5", pki.client, pki.ca)))
            with _rm_through(endpoint, server.port) as env:
                local = Arena(seed=5)
                assert same(env.reset(), local.reset())
                for _ in range(3):
                    actions = [int(np.flatnonzero(m)[0]) for m in local.get_avail_actions()]
                    assert same(env.step(actions), local.step(actions))
                local.close()
            monkeypatch.setenv(TLS_ENV, str(_tls_file(tmp_path / "m.json5", pki.monitor, pki.ca)))
            with pytest.raises(ServerUnavailableError, match="no NeuronsMAE server answers"):
                RM(port=server.port, router=endpoint, timeout=2.0)  # connected, but denied
            monkeypatch.delenv(TLS_ENV)
            with pytest.raises(ServerUnavailableError, match="cannot reach the Zenoh router"):
                RM(port=server.port, router=endpoint, timeout=2.0)  # refused at the handshake
        finally:
            server.stop()
    finally:
        router.close()
