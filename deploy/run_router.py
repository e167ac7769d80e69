"""Run a Zenoh router for NeuronsMAE servers and clients on different machines.

    python deploy/run_router.py [--config deploy/zenoh-router.json5]
                                [--listen tcp/0.0.0.0:7447]

Opens one Zenoh session in ``router`` mode (the configuration file's settings, then
``--listen`` if given) and keeps it open until SIGINT or SIGTERM. This is the same router
as Zenoh's ``zenohd`` minus the plugins, runnable with nothing but the ``eclipse-zenoh``
package the project already depends on. See ``deploy/README.md``.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import zenoh

CONFIG = Path(__file__).resolve().parent / "zenoh-router.json5"


def router_config(config: Path | None, listen: Sequence[str]) -> zenoh.Config:
    """The router's configuration: the file (if any), forced into router mode, with
    ``listen`` replacing its listen endpoints when given, and scouting off by default."""
    if config is not None:
        conf = zenoh.Config.from_file(str(config))
    else:
        conf = zenoh.Config()
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("scouting/gossip/enabled", "false")
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/0.0.0.0:7447"]))
    conf.insert_json5("mode", '"router"')
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return conf


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
        help="listen here instead of the file's endpoints (repeatable), e.g. tcp/0.0.0.0:7447",
    )
    args = p.parse_args(argv)
    stopped: list[int] = []  # a plain list, not an Event: a handler must never take a lock
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stopped.append(signum))
    try:
        session = zenoh.open(router_config(args.config, args.listen))
    except zenoh.ZError as exc:
        sys.stderr.write(f"run_router.py: cannot start the router: {exc}\n")
        return 1
    try:
        listening = args.listen or "the configured endpoints"
        sys.stderr.write(f"run_router.py: router {session.zid()} listening on {listening}\n")
        sys.stderr.flush()
        while not stopped:
            time.sleep(0.2)
    finally:
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
