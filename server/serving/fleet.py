"""``neuronsmae-fleet``: start N arena servers on consecutive ports and keep them up.

    neuronsmae-fleet --base-port 10000 --count 8 --seed 1 [--arenas 1] [--host 127.0.0.1]
                     [--time-scale 100] [--router tcp/10.0.0.1:7447] [--interval 2]
    neuronsmae-fleet status --base-port 10000 --count 8 [--json]
    python -m neuronsmae.server.serving.fleet ...   (the same, without the console script)

``neuronsmae-serve``, the command's former name, still runs it after a one-line
deprecation note on stderr (:func:`deprecated_main`); it will be removed.

Server ``i`` listens on ``base_port + i`` and holds ``--arenas`` arenas (1 by default) seeded
``seed + i * arenas`` onward, as a subprocess of its own
(``python -m neuronsmae.server``), never a fork, because this process holds Zenoh sessions
for the pings. Server 0 starts first and the rest only once it answers, so the numba
kernels are compiled (and cached on disk) once rather than by all N at once. Every
``--interval`` seconds each server is pinged through the protocol's ``ping`` message; a
server that exited is started again (with a growing delay while it keeps dying), and one
that misses ``--max-missed`` pings in a row is killed and started again (0: never).
SIGINT/SIGTERM stop every server (SIGTERM, then SIGKILL after 10 s) and exit 0. The pids
are written to a state file so that ``status`` can show them next to each server's health;
a fleet writes it only once it has taken it, before any server starts (see
:mod:`neuronsmae.server.serving.statefile`).

Exit status: 0 after a signal, 2 on bad arguments (``$NEURONSMAE_STATE_DIR`` included) or
when a server cannot start at all (its port is taken, the state file is another running
fleet's or no fleet's), 1 for ``status`` when any server is down.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from neuronsmae.protocol.defaults import DEFAULT_HOST, DEFAULT_PORT, DEFAULT_SEED
from neuronsmae.protocol.errors import NeuronsMAEError
from neuronsmae.protocol.launch import check_timeout
from neuronsmae.server.serving.locators import check_endpoint
from neuronsmae.server.serving.probe import Probe
from neuronsmae.server.serving.rpc import check_listen_host
from neuronsmae.server.serving.statefile import StateFileError, load, pid_alive, state_path
from neuronsmae.server.serving.supervisor import (
    BAD_ARGUMENTS,
    Fleet,
    FleetSpec,
    FleetStartError,
    StopFlag,
    check_interval,
)

log = logging.getLogger("neuronsmae.serve")

COMMAND = "neuronsmae-fleet"
"""The fleet's command (one server alone is ``neuronsmae-server``)."""
OLD_COMMAND = "neuronsmae-serve"
"""The fleet command's former name, a deprecated alias of :data:`COMMAND`."""

# ---- status --------------------------------------------------------------------------------


def read_state(path: Path) -> dict[int, dict[str, object]]:
    """Port → recorded server entry, from a running fleet's state file (empty if none, and
    with a warning naming the file when it is unreadable or no fleet's state)."""
    try:
        state = load(path)
    except StateFileError as exc:
        log.warning("%s; ignoring it (no pids shown)", exc)
        return {}
    if state is None or not pid_alive(state.get("fleet_pid")):
        return {}
    return {s["port"]: s for s in state.get("servers", [])}


def status(
    spec: FleetSpec, state_file: Path | None = None, timeout: float = 1.0
) -> list[dict[str, object]]:
    """Ping every server of ``spec``; one row per port with its pid when a fleet runs it."""
    recorded = read_state(state_file or state_path(spec.base_port))
    rows = []
    for port in spec.ports():
        router = spec.routers[0] if spec.routers else None
        with Probe(spec.host, port, router, timeout) as probe:
            health = probe.ping()
        entry = recorded.get(port, {})
        pid = entry.get("pid")
        rows.append(
            {
                "port": port,
                "pid": pid if pid_alive(pid) else None,
                "state": "up" if health.up else "down",
                "ping_ms": None if health.ms is None else round(health.ms, 2),
                "server": (health.server or "")[:8],
                "owned": health.owned,
                "starts": entry.get("starts"),
                "error": health.error,
            }
        )
    return rows


def format_status(rows: list[dict[str, object]]) -> str:
    """A plain text table of :func:`status` rows."""
    lines = [f"{'port':>6} {'pid':>8} {'state':<5} {'ping_ms':>8} {'server':<8} owned  note"]
    for r in rows:
        ms = "-" if r["ping_ms"] is None else f"{r['ping_ms']:.2f}"
        owned = "-" if r["owned"] is None else ("yes" if r["owned"] else "no")
        lines.append(
            f"{r['port']:>6} {r['pid'] or '-':>8} {r['state']:<5} {ms:>8} "
            f"{r['server'] or '-':<8} {owned:<6} {r['error']}"
        )
    return "\n".join(lines)


# ---- command line --------------------------------------------------------------------------


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--base-port", type=int, default=DEFAULT_PORT, help=f"port of server 0 ({DEFAULT_PORT})"
    )
    p.add_argument("--count", type=int, default=1, help="number of servers (1)")
    p.add_argument(
        "--host", default=DEFAULT_HOST, help=f"address the servers listen on ({DEFAULT_HOST})"
    )
    p.add_argument(
        "--router",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh router the servers also connect to (e.g. tcp/10.0.0.1:7447); status "
        "pings through the first one",
    )
    p.add_argument("--state-file", type=Path, default=None, help=argparse.SUPPRESS)
    p.add_argument("--ping-timeout", type=float, default=1.0, help="seconds per ping (1)")


def _run_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=COMMAND,
        description="Run N NeuronsMAE servers on consecutive ports and restart any that die "
        "(one server alone: neuronsmae-server).",
        epilog=f"`{COMMAND} status --base-port P --count N` lists their health.",
    )
    _common(p)
    p.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help=f"seed of server 0's first arena; +1 per arena ({DEFAULT_SEED})",
    )
    p.add_argument(
        "--arenas",
        type=int,
        default=1,
        help="arenas per server, stepped together by one vector request (1)",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=100.0,
        help="servers' pace cap; 0 = unlimited (100, the released build's)",
    )
    p.add_argument("--lease", type=float, default=60.0, help="servers' ownership lease (60)")
    p.add_argument("--interval", type=float, default=2.0, help="seconds between checks (2)")
    p.add_argument(
        "--max-missed",
        type=int,
        default=0,
        help="restart a server after this many missed pings in a row (0: only when it exits)",
    )
    p.add_argument("--log-dir", type=Path, default=None, help="servers' logs (a temp folder)")
    p.add_argument(
        "--server-log-level", default="WARNING", choices=["DEBUG", "INFO", "WARNING", "ERROR"]
    )
    return p


def _status_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog=f"{COMMAND} status", description="Ping the servers of a fleet."
    )
    _common(p)
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def _spec(args: argparse.Namespace, **extra: object) -> FleetSpec:
    if not (args.base_port > 0 and args.base_port + args.count <= 65536 and args.count >= 1):
        raise ValueError(
            f"--base-port {args.base_port} --count {args.count}: --count must be ≥ 1 and "
            "every port (--base-port to --base-port + --count - 1) in 1..65535"
        )
    for router in args.router:
        check_endpoint(router, "--router")
    return FleetSpec(
        base_port=args.base_port,
        count=args.count,
        host=args.host,
        routers=tuple(args.router),
        **extra,  # type: ignore[arg-type]
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``neuronsmae-fleet`` (``run`` is the default subcommand)."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(stream=sys.stderr, level=logging.INFO, format=f"{COMMAND}: %(message)s")
    if args_in[:1] == ["status"]:
        return _status_main(args_in[1:])
    return _run_main(args_in[1:] if args_in[:1] == ["run"] else args_in)


def deprecated_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``neuronsmae-serve``, the former name: one line on stderr saying to use
    ``neuronsmae-fleet``, then exactly what ``neuronsmae-fleet`` does."""
    sys.stderr.write(
        f"{OLD_COMMAND} is deprecated and will be removed: use {COMMAND} (the same command)\n"
    )
    sys.stderr.flush()
    return main(argv)


def _status_main(argv: list[str]) -> int:
    parser = _status_parser()
    args = parser.parse_args(argv)
    try:
        spec = _spec(args)
        check_timeout(args.ping_timeout, "--ping-timeout")
    except (ValueError, NeuronsMAEError) as exc:
        parser.error(str(exc))
    rows = status(spec, args.state_file, args.ping_timeout)
    sys.stdout.write((json.dumps(rows, indent=1) if args.json else format_status(rows)) + "\n")
    return 0 if all(r["state"] == "up" for r in rows) else 1


def _run_main(argv: list[str]) -> int:
    parser = _run_parser()
    args = parser.parse_args(argv)
    try:
        spec = _spec(
            args,
            seed=args.seed,
            time_scale=args.time_scale,
            lease=args.lease,
            log_level=args.server_log_level,
            arenas=args.arenas,
        )
        check_timeout(args.ping_timeout, "--ping-timeout")
        check_interval(args.interval)
        check_listen_host(args.host, "--host")
        fleet = Fleet(spec, args.log_dir, args.state_file, args.ping_timeout, args.max_missed)
    except (ValueError, NeuronsMAEError) as exc:
        parser.error(str(exc))
    stop = StopFlag()
    stop.install()
    try:
        with fleet:
            fleet.start(stop=stop)
            if not stop.set:
                ports = f"{spec.base_port}..{spec.base_port + spec.count - 1}"
                log.info(
                    "serving %d arenas (%d servers × %d) on %s ports %s; logs in %s; state in %s",
                    spec.count * spec.arenas,
                    spec.count,
                    spec.arenas,
                    spec.host,
                    ports,
                    fleet.log_dir,
                    fleet.state_file,
                )
                fleet.run(stop, args.interval)
    except FleetStartError as exc:
        log.error("%s", exc)
        return BAD_ARGUMENTS
    log.info("all servers stopped (%d restarts)", fleet.restarts)
    return 0


if __name__ == "__main__":
    sys.exit(main())
