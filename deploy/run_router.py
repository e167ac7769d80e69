"""Run a Zenoh router for NeuronsMAE servers and clients on different machines.

    python deploy/run_router.py [--config deploy/zenoh-router.json5]
                                [--listen tcp/10.0.0.1:7447]

Opens one Zenoh session in ``router`` mode (the configuration file's settings, then
``--listen`` if given) and keeps it open until SIGINT or SIGTERM. This is the same router
as Zenoh's ``zenohd`` minus the plugins, runnable with nothing but the ``eclipse-zenoh``
package the project already depends on. See ``deploy/README.md``.

Like the servers, the router listens on loopback unless told otherwise (the file or
``--listen``), and says so on stderr when it listens anywhere else: the protocol does not
authenticate clients, so reaching a network must be a deliberate choice. For a network, use
``deploy/zenoh-router-tls.json5`` (mutual TLS) and ``deploy/zenoh-router-acl.json5``.

What a ``--config`` file leaves out takes this script's defaults, not Zenoh's: no listen
endpoints means ``tcp/127.0.0.1:7447`` (Zenoh's own default is ``tcp/[::]:7447``, every
interface), and no ``scouting.multicast.enabled`` / ``scouting.gossip.enabled`` means off
(Zenoh's default is on). Each default applied is named on stderr. A file's listen endpoints
equal to Zenoh's per-mode default cannot be told from none and count as none: to listen on
every interface, list the endpoints (``endpoints: ["tcp/[::]:7447"]``) or use ``--listen``.
"""

from __future__ import annotations

import argparse
import ipaddress
import json
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.transport import zenoh_message
from neuronsmae.server.serving.locators import check_endpoint

CONFIG = Path(__file__).resolve().parent / "zenoh-router.json5"
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def exposed(endpoints: Sequence[str], mtls: bool = False) -> list[str]:
    """The endpoints (``proto/host:port``) open to a network without authentication: not on
    a loopback address, and not TLS with client certificates required (``mtls``)."""
    out = []
    for ep in endpoints:
        proto, _, address = ep.partition("/")
        if proto == "tls" and mtls:
            continue
        host = address.split("#", 1)[0].rsplit(":", 1)[0].strip("[]")
        try:
            loopback = host == "localhost" or ipaddress.ip_address(host).is_loopback
        except ValueError:  # a host name: it may resolve to anything
            loopback = False
        if not loopback:
            out.append(ep)
    return out


def router_config(config: Path | None, listen: Sequence[str]) -> zenoh.Config:
    """The router's configuration: the file (if any), forced into router mode, with
    ``listen`` replacing its listen endpoints when given, and :func:`apply_defaults` for
    whatever the file leaves out."""
    return build_config(config, listen)[0]


def build_config(config: Path | None, listen: Sequence[str]) -> tuple[zenoh.Config, list[str]]:
    """:func:`router_config`, and which of this script's defaults it applied."""
    conf = zenoh.Config() if config is None else zenoh.Config.from_file(str(config))
    conf.insert_json5("mode", '"router"')
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return conf, apply_defaults(conf)


def apply_defaults(conf: zenoh.Config) -> list[str]:
    """Fill in this script's safe defaults where ``conf`` sets nothing, in place: listen on
    loopback only, no multicast or gossip scouting. Return what was filled in.

    Zenoh reports an unset scouting switch as null; unset listen endpoints come back as
    Zenoh's own per-mode default (every interface), so that value counts as unset."""
    applied = []
    for switch in ("multicast", "gossip"):
        key = f"scouting/{switch}/enabled"
        if json.loads(conf.get_json(key)) is None:
            conf.insert_json5(key, "false")
            applied.append(f"{switch} scouting off")
    if conf.get_json("listen/endpoints") == zenoh.Config().get_json("listen/endpoints"):
        conf.insert_json5("listen/endpoints", json.dumps([DEFAULT_LISTEN]))
        applied.append(f"listen on {DEFAULT_LISTEN}")
    return applied


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="run_router.py", description=__doc__.split("\n")[0])
    p.add_argument(
        "--config",
        type=Path,
        default=CONFIG if CONFIG.is_file() else None,
        help=f"Zenoh JSON5 configuration ({CONFIG.name} beside this script)",
    )
    p.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="listen here instead of the file's endpoints (repeatable), e.g. tcp/10.0.0.1:7447",
    )
    args = p.parse_args(argv)
    for endpoint in args.listen:
        try:
            check_endpoint(endpoint, "--listen", listen=True)
        except InvalidOptionError as exc:
            p.error(str(exc))
    if args.config is not None and not args.config.is_file():
        p.error(f"--config {args.config}: no such file")
    try:
        conf, defaults = build_config(args.config, args.listen)
    except zenoh.ZError as exc:  # the file is no Zenoh configuration, or a bad endpoint
        p.error(f"--config {args.config}: not a usable Zenoh configuration: {zenoh_message(exc)}")
    if args.config is not None and defaults:
        sys.stderr.write(
            f"run_router.py: {args.config} leaves out settings; using this script's safe "
            f"defaults, not Zenoh's: {', '.join(defaults)}\n"
        )
    endpoints = json.loads(conf.get_json("listen/endpoints"))
    if isinstance(endpoints, dict):  # per-mode form: {router: [...], peer: [...]}
        endpoints = endpoints.get("router", [])
    for endpoint in endpoints if not args.listen else []:
        try:
            check_endpoint(endpoint, f"--config {args.config}: a listen endpoint", listen=True)
        except InvalidOptionError as exc:
            p.error(str(exc))
    stopped: list[int] = []  # a plain list, not an Event: a handler must never take a lock
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stopped.append(signum))
    mtls = json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    for ep in exposed(endpoints, mtls):
        sys.stderr.write(
            f"run_router.py: WARNING: listening on {ep}, not on loopback: anyone who can reach "
            "it can reach every server behind this router; use mutual TLS "
            "(deploy/zenoh-router-tls.json5) and access control (deploy/zenoh-router-acl.json5)\n"
        )
    try:
        session = zenoh.open(conf)
    except zenoh.ZError as exc:
        sys.stderr.write(f"run_router.py: cannot start the router: {zenoh_message(exc)}\n")
        return 1
    try:
        listening = ", ".join(map(str, endpoints)) or "no endpoint"
        sys.stderr.write(f"run_router.py: router {session.zid()} listening on {listening}\n")
        sys.stderr.flush()
        while not stopped:
            time.sleep(0.2)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
