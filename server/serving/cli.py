"""``neuronsmae-server``: serve arenas over Zenoh on one TCP port.

    neuronsmae-server --port 10000 --seed 1234 [--arenas 1] [--time-scale 100]
                      [--no-graphics] [--host 127.0.0.1]

One arena by default (the released build's one environment per port); ``--arenas K`` holds
K arenas, seeded ``seed + i``, that one vector request steps together.

Exit status: 0 after a SIGTERM/SIGINT shutdown, 2 when the port is taken or the arguments
are wrong, 1 when the arena or Zenoh fails to start.
"""

from __future__ import annotations

import argparse
import ipaddress
import logging
import math
import os
import subprocess
import sys
from collections.abc import Sequence

import zenoh

from neuronsmae.protocol.defaults import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    DEFAULT_SEED,
    RELEASED_TIME_SCALE,
)
from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.messages import MAX_ARENAS, max_first_seed
from neuronsmae.protocol.transport import MAX_BUSY_POLL_US, zenoh_message
from neuronsmae.server.arena import Arena
from neuronsmae.server.contexts import context_table
from neuronsmae.server.serving.locators import check_endpoint
from neuronsmae.server.serving.rpc import (
    Interrupted,
    PortInUseError,
    RpcServer,
    StopSignal,
    check_listen_host,
    check_port,
    watch_parent,
)
from neuronsmae.server.serving.service import DEFAULT_LEASE_S, ArenaService, warm_up
from neuronsmae.server.sim.kernel_cache import compile_aside

log = logging.getLogger("neuronsmae.server")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="neuronsmae-server", description="Serve NeuronsMAE arenas over Zenoh on one port."
    )
    p.add_argument(
        "--port", type=int, default=DEFAULT_PORT, help=f"TCP port to listen on ({DEFAULT_PORT})"
    )
    p.add_argument(
        "--seed",
        type=int,
        default=DEFAULT_SEED,
        help="arena seed used until a client configures its own (1234)",
    )
    p.add_argument(
        "--arenas",
        type=int,
        default=1,
        help=f"arenas held, seeded seed, seed+1, ...; one vector request steps them all "
        f"(1; at most {MAX_ARENAS})",
    )
    p.add_argument(
        "--time-scale",
        type=float,
        default=RELEASED_TIME_SCALE,
        help=f"cap on simulated/real time ratio; 0 = unlimited ({RELEASED_TIME_SCALE:g})",
    )
    p.add_argument(
        "--no-graphics",
        action="store_true",
        help="accepted for compatibility and ignored; a 3-D window opens only with the gui "
        "option (docs/options.md)",
    )
    p.add_argument(
        "--host",
        default=DEFAULT_HOST,
        help="address to listen on (127.0.0.1; 0.0.0.0 for remote clients, which logs a warning)",
    )
    p.add_argument(
        "--router",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="also connect to this Zenoh router (e.g. tcp/10.0.0.1:7447), so clients that "
        "cannot reach --host reach the server through it (repeatable)",
    )
    p.add_argument(
        "--lease",
        type=float,
        default=DEFAULT_LEASE_S,
        help="seconds of silence after which another client may take over (60)",
    )
    p.add_argument(
        "--busy-poll",
        type=float,
        default=0.0,
        metavar="MICROSECONDS",
        help="after each reply, poll for the next request this long before sleeping: "
        "faster round trips for one client with a spare core, wasted CPU when servers "
        f"share cores (0 = never; at most {MAX_BUSY_POLL_US:g})",
    )
    p.add_argument(
        "--log-level",
        default="WARNING",
        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
        type=str.upper,
        help="logging level (WARNING)",
    )
    p.add_argument("--watch-parent", type=int, default=None, help=argparse.SUPPRESS)
    p.add_argument(
        "--compile-only",
        action="store_true",
        help="compile the simulation's kernels into the cache and exit (servers do this in a "
        "throwaway process before serving)",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point: :func:`run`, then leave at once when run as a program.

    Called without ``argv`` (as the ``neuronsmae-server`` script or ``python -m``), the
    process exits straight after the orderly shutdown (arena and Zenoh session closed, logs
    flushed) instead of through interpreter teardown: finalising numba and PyBullet takes
    about half a second, which would break the promise of stopping within 1 s of SIGTERM.
    """
    status = run(argv)
    if argv is None:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


def invalid_arguments(args: argparse.Namespace) -> list[str]:
    """What is wrong with the parsed arguments, one message per argument naming what is
    valid (empty when all are)."""
    problems = []
    if not 0 < args.port < 65536:
        problems.append(f"--port must be in 1..65535, got {args.port}")
    top = max_first_seed(max(args.arenas, 1))
    if not 0 <= args.seed <= top:
        problems.append(f"--seed must be in 0..{top} (arena i is seeded seed + i), got {args.seed}")
    if not 1 <= args.arenas <= MAX_ARENAS:
        problems.append(f"--arenas must be in 1..{MAX_ARENAS}, got {args.arenas}")
    if not (math.isfinite(args.time_scale) and args.time_scale >= 0):
        problems.append(f"--time-scale must be a finite number >= 0, got {args.time_scale:g}")
    if not (math.isfinite(args.lease) and args.lease > 0):
        problems.append(f"--lease must be a finite number of seconds > 0, got {args.lease:g}")
    for router in args.router:
        try:
            check_endpoint(router, "--router")
        except InvalidOptionError as exc:
            problems.append(str(exc))
    try:
        check_listen_host(args.host, "--host")
    except InvalidOptionError as exc:
        problems.append(str(exc))
    if not 0 <= args.busy_poll <= MAX_BUSY_POLL_US:
        problems.append(
            f"--busy-poll must be in 0..{MAX_BUSY_POLL_US:g} microseconds, got {args.busy_poll:g}"
        )
    return problems


def run(argv: Sequence[str] | None = None) -> int:
    """Run the server until SIGTERM/SIGINT; return the process exit status."""
    args = _parser().parse_args(argv)
    logging.basicConfig(
        stream=sys.stderr,
        level=args.log_level,
        format="neuronsmae-server[%(process)d] %(levelname)s: %(message)s",
    )
    problems = invalid_arguments(args)
    if problems:
        for problem in problems:
            log.error("%s", problem)
        return 2
    if args.compile_only:
        warm_up(Arena)
        return 0
    compile_first()
    warning = exposure_warning(args.host, args.port)
    if warning:
        log.warning("%s", warning)
    stop = StopSignal()
    stop.install()
    if args.watch_parent is not None:
        watch_parent(args.watch_parent)
    try:
        check_port(args.host, args.port)
        return _serve(args, stop)
    except PortInUseError as exc:
        log.error("%s; stop the server using it or choose another --port", exc)
        return 2
    except Interrupted:
        return 0
    except zenoh.ZError as exc:
        log.error("cannot start: %s", zenoh_message(exc))
        return 1
    except (OSError, NeuronsMAEError) as exc:
        log.error("cannot start: %s", exc)
        return 1


def exposure_warning(host: str, port: int) -> str | None:
    """The warning to log when ``host`` is not a loopback address, else None.

    Why warn: the protocol identifies clients but does not authenticate them (see
    ``protocol/README.md``), so a server reachable from a network can be driven by anyone on
    it. Listening there must be a visible, deliberate choice.
    """
    name = host.strip("[]")
    if name == "localhost":
        return None
    try:
        if ipaddress.ip_address(name).is_loopback:
            return None
    except ValueError:  # a host name: it may resolve to anything
        pass
    return (
        f"listening on {host}:{port}, not on loopback: anyone who can reach it can drive "
        "this arena (the protocol has no authentication); expose it only on a trusted "
        "network, or keep it on loopback behind a TLS router (deploy/zenoh-router-tls.json5)"
    )


def compile_first() -> None:
    """Have a throwaway ``neuronsmae-server --compile-only`` compile the kernels unless they
    are cached for this checkout, so this process loads them instead of compiling them (see
    ``server/sim/kernel_cache.py``: compiling keeps about 150 MB more resident per server).
    Runs before the Zenoh session opens: a process with a session must not fork."""
    try:
        if compile_aside([sys.executable, "-m", "neuronsmae.server", "--compile-only"]):
            log.info("kernels compiled in a throwaway process")
    except (OSError, subprocess.SubprocessError) as exc:
        detail = getattr(exc, "stderr", b"") or b""
        log.warning("compiling aside failed (%s) %s; compiling here", exc, detail[-500:])


def _serve(args: argparse.Namespace, stop: StopSignal) -> int:
    service = ArenaService(
        Arena,
        seed=args.seed,
        time_scale=args.time_scale,
        lease_s=args.lease,
        context_table=context_table,
        arenas=args.arenas,
    )
    rpc = RpcServer(service, args.host, args.port, stop, args.router, args.busy_poll * 1e-6)
    with service, rpc as server:
        server.serve_forever()
    return 0
