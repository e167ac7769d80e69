"""The transport's floor: the round trip of a bare Zenoh query, and of a bare TCP socket.

    python -m bench.zenoh_floor [--pings 3000]

Why: ``bench_transport`` compares ``RM`` with the in-process ``Arena``, and every decision
over ``RM`` is one Zenoh query. A query's round trip with nothing of NeuronsMAE in it (no
codec, no arena, a one-byte reply from a process that does nothing else, the same session
settings as ``protocol.transport``) is a cost no change to this project can remove, so it
bounds the ratio: ``in_process_us / (in_process_us + floor_us)`` even if the server and
client cost nothing. The same exchange as a publication answered by a publication (Zenoh's
other request pattern), and over a plain TCP socket between two Python processes, shows how
much of the floor is the pattern's, Zenoh's and the operating system's.

The vector path's floor (``--arenas K``, 8 by default): the CPU, all threads of both
processes, of a bare query answered after the server has kept its core busy for as long as
K in-process decisions take (measured first, in this run) with a reply as big as a K-arena
``vstep`` reply. The client's core idles meanwhile, as it does while a vector server steps
its arenas, and waking from that idle is what most of this floor pays for. Divided by K,
it bounds ``bench_vector``'s CPU ratio: ``decision_us / (decision_us + floor_us / K)``.
Measured twice: with a server that spins through the hold (its caches stay as the query
left them: the lowest floor), and with one that steps K real arenas (their CPU, which it
reports in each reply, is subtracted): its caches then end up as full of the arenas' data as
a vector server's, and every query is handled cold, as served requests are. The second is
the floor of a vector server whose own request handling costs nothing;
``bench.request_cost`` times that handling, warm and cold.

Prints Markdown tables and writes bench/out/zenoh_floor.json.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import zenoh

from bench.common import (
    MAX_ARENAS,
    at_least,
    between,
    cpu_by_thread,
    cpu_snapshot,
    free_port,
    machine,
    non_negative,
    table,
    tcp_port,
    write_json,
)
from neuronsmae.protocol.transport import client_config, server_config
from neuronsmae.server.serving.rpc import next_query

KEY = "bench/floor"
READY_S = 20.0


class NoReply(RuntimeError):
    """An echo server did not answer (yet: retried until ``READY_S``)."""


REPO = Path(__file__).resolve().parents[1]


class ArenaHold:
    """Holds each query by stepping K in-process arenas once (random allowed actions), and
    counts the CPU that took in this thread."""

    def __init__(self, arenas: int) -> None:
        from neuronsmae.server.vec import VecArena

        self.env = VecArena(seed=1, num_envs=arenas)
        self.env.reset()
        self.rng = np.random.default_rng(0)
        self.held_ns = 0
        """CPU nanoseconds spent stepping the arenas so far."""

    def __call__(self) -> None:
        start = time.thread_time_ns()
        avail = self.env.get_avail_actions()
        self.env.step((avail * self.rng.random(avail.shape)).argmax(-1))
        self.held_ns += time.thread_time_ns() - start


def serve_zenoh(
    port: int,
    busy_poll_s: float = 0.0,
    hold_s: float = 0.0,
    reply_bytes: int = 1,
    hold_arenas: int = 0,
) -> None:
    """Answer every query on ``KEY`` with ``reply_bytes`` bytes, until killed; poll
    ``busy_poll_s`` for the next query before blocking, exactly as ``neuronsmae-server
    --busy-poll`` does. Before replying, spin ``hold_s`` (the core busy, its caches as the
    query left them) or step ``hold_arenas`` in-process arenas once (the core busy as a
    vector server's is, its caches full of the arenas' data); the reply then starts with
    the CPU nanoseconds all holds took so far (8 bytes, big-endian). A spin runs until its
    thread has spent ``hold_s`` of CPU, so a preempted spin still costs what it reports."""
    session = zenoh.open(server_config("127.0.0.1", port))
    hold = ArenaHold(hold_arenas) if hold_arenas > 0 else None
    filler = b"x" * max(reply_bytes - 8, 0)
    spun = 0
    try:
        queryable = session.declare_queryable(KEY)
        while True:
            with next_query(queryable, busy_poll_s) as query:
                start = time.thread_time_ns()
                end = start + int(hold_s * 1e9)
                while time.thread_time_ns() < end:
                    pass
                spun += time.thread_time_ns() - start
                if hold is not None:
                    hold()
                held = spun + (hold.held_ns if hold is not None else 0)
                query.reply(KEY, held.to_bytes(8, "big") + filler, express=True)
    finally:
        session.close()


def serve_pubsub(port: int) -> None:
    """Publish one byte on ``KEY/rep`` for every sample on ``KEY/req``, until killed."""
    session = zenoh.open(server_config("127.0.0.1", port))
    try:
        publisher = session.declare_publisher(f"{KEY}/rep", express=True)
        subscriber = session.declare_subscriber(f"{KEY}/req")
        while True:
            subscriber.recv()
            publisher.put(b"x")
    finally:
        session.close()


def serve_tcp(port: int) -> None:
    """Echo one byte for every message of the first connection, until it closes."""
    with socket.create_server(("127.0.0.1", port)) as server:
        conn, _ = server.accept()
        with conn:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            while conn.recv(64):
                conn.sendall(b"x")


POLL_S = 2e-3
"""How long the polling echo server polls: as ``bench_transport``'s default busy poll."""
HELD_REPLY_BYTES = 6_000
"""A K = 8 ``vstep`` reply of the abstract 2 v 2 task: 5.9 KB."""
HOLDS = ("spin", "arenas")
"""How a held echo server keeps its core busy (see :func:`held_floor`)."""


SERVERS: dict[str, Callable[[int], None]] = {
    "zenoh": serve_zenoh,
    "zenoh-poll": lambda port: serve_zenoh(port, POLL_S),
    "pubsub": serve_pubsub,
    "tcp": serve_tcp,
}


@contextlib.contextmanager
def spawned(kind: str, port: int, *extra: str) -> Iterator[subprocess.Popen[bytes]]:
    """A fresh process (never a fork of one holding a Zenoh session) serving ``kind``."""
    cmd = [sys.executable, "-m", "bench.zenoh_floor", "--serve", kind, "--port", str(port)]
    cmd += extra
    proc = subprocess.Popen(cmd, cwd=REPO)
    try:
        yield proc
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _until_ready(connect: Callable[[], object]) -> object:
    deadline = time.monotonic() + READY_S
    while True:
        try:
            return connect()
        except (zenoh.ZError, OSError, NoReply):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def _stats(kind: str, times: list[float]) -> dict[str, object]:
    times = sorted(times)
    return {
        "path": kind,
        "pings": len(times),
        "median_us": round(statistics.median(times) * 1e6, 1),
        "p99_us": round(times[int(0.99 * (len(times) - 1))] * 1e6, 1),
    }


def _timed(call: Callable[[], object], pings: int, warm: int = 200) -> list[float]:
    for _ in range(warm):
        call()
    times = []
    for _ in range(pings):
        start = time.perf_counter()
        call()
        times.append(time.perf_counter() - start)
    return times


@contextlib.contextmanager
def _echo_query(
    kind: str, payload: bytes, *extra: str
) -> Iterator[tuple[subprocess.Popen[bytes], Callable[[], bytes]]]:
    """A ``kind`` echo server on a free port and a call that queries it once with
    ``payload`` through the project's own session settings (answering when yielded)."""
    port = free_port()
    with spawned(kind, port, *extra) as proc:
        session = _until_ready(lambda: zenoh.open(client_config("127.0.0.1", port)))
        assert isinstance(session, zenoh.Session)
        try:
            querier = session.declare_querier(
                KEY, timeout=5.0, consolidation=zenoh.ConsolidationMode.NONE, express=True
            )

            def call() -> bytes:
                replies = list(querier.get(payload=payload))
                if not replies or replies[0].ok is None:  # the server is still declaring
                    raise NoReply("no reply from the echo server")
                return replies[0].ok.payload.to_bytes()

            _until_ready(call)
            yield proc, call
        finally:
            session.close()


def zenoh_rtt(pings: int, poll: bool = False) -> dict[str, object]:
    """Round trips of a one-byte query through the project's own session settings, to a
    server that sleeps until a query comes or (``poll``) polls for it first."""
    with _echo_query("zenoh-poll" if poll else "zenoh", b"p") as (_, call):
        name = "zenoh query, server polling" if poll else "zenoh query"
        return _stats(name, _timed(call, pings))


def pubsub_rtt(pings: int) -> dict[str, object]:
    """Round trips of one byte published to the echo server and published back: Zenoh's
    other request pattern (``bench_rpc_styles`` compares both with the real service)."""
    port = free_port()
    with spawned("pubsub", port):
        session = _until_ready(lambda: zenoh.open(client_config("127.0.0.1", port)))
        assert isinstance(session, zenoh.Session)
        try:
            publisher = session.declare_publisher(f"{KEY}/req", express=True)
            subscriber = session.declare_subscriber(f"{KEY}/rep")
            deadline = time.monotonic() + READY_S
            while subscriber.try_recv() is None:  # until both declarations have met
                if time.monotonic() > deadline:
                    raise NoReply("no reply from the echo server")
                publisher.put(b"p")
                time.sleep(0.05)
            time.sleep(0.2)
            while subscriber.try_recv() is not None:  # replies to the probes above
                pass

            def call() -> None:
                publisher.put(b"p")
                subscriber.recv()

            return _stats("zenoh publish/subscribe", _timed(call, pings))
        finally:
            session.close()


def tcp_rtt(pings: int) -> dict[str, object]:
    """Round trips of one byte over a loopback TCP socket between two Python processes."""
    port = free_port()
    with spawned("tcp", port):
        conn = _until_ready(lambda: socket.create_connection(("127.0.0.1", port)))
        assert isinstance(conn, socket.socket)
        with conn:
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

            def call() -> None:
                conn.sendall(b"p")
                if not conn.recv(64):
                    raise RuntimeError("the echo server closed the connection")

            return _stats("tcp socket", _timed(call, pings))


def decision_us(arenas: int, steps: int = 60) -> float:
    """CPU µs of one in-process decision, ``arenas`` arenas stepped together with random
    allowed actions (``bench_vector``'s loop)."""
    from bench.bench_vector import measure, play
    from neuronsmae.server.vec import VecArena

    env = VecArena(seed=1, num_envs=arenas)
    try:
        env.reset()
        play(env, 3, np.random.default_rng(0))
        return measure(env, steps, 1, [psutil.Process()])[1]
    finally:
        env.close()


def held_floor(
    pings: int, arenas: int, reply_bytes: int = HELD_REPLY_BYTES, hold: str = "spin"
) -> dict[str, Any]:
    """The vector path's floor: CPU µs per query to a server that holds each one for
    ``arenas`` in-process decisions, by thread, less the hold itself; and the CPU ratio it
    alone allows ``bench_vector`` at that K. ``hold``: ``"spin"`` spins for the CPU the
    decisions take (measured first, here); ``"arenas"`` has the server step ``arenas`` real
    arenas and subtracts the CPU those steps took (which the server reports)."""
    if hold not in HOLDS:
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    decision = decision_us(arenas)
    hold_s = decision * arenas / 1e6
    how = ("--hold-ms", f"{hold_s * 1e3:.3f}") if hold == "spin" else ("--hold-arenas", str(arenas))
    extra = (*how, "--reply-bytes", str(reply_bytes))
    with _echo_query("zenoh-held", b"p" * 300, *extra) as (proc, call):
        for _ in range(5):
            first = call()
        procs = [psutil.Process(), psutil.Process(proc.pid)]
        before = cpu_snapshot(procs)
        for _ in range(pings):
            last = call()
        split = cpu_by_thread(before, cpu_snapshot(procs), [p.pid for p in procs])
    (client_main, client_other), (server_main, server_other) = (
        [seconds / pings * 1e6 for seconds in row] for row in split
    )
    held_ns = int.from_bytes(last[:8], "big") - int.from_bytes(first[:8], "big")
    hold_s = held_ns / 1e9 / pings  # the CPU the holds took, as the server measured it
    server_main -= hold_s * 1e6
    floor = client_main + client_other + server_main + server_other
    return {
        "hold": hold,
        "arenas": arenas,
        "in_process_decision_us": round(decision, 1),
        "hold_ms": round(hold_s * 1e3, 2),
        "reply_bytes": reply_bytes,
        "pings": pings,
        "client_main_us": round(client_main, 1),
        "client_other_us": round(client_other, 1),
        "server_main_us": round(server_main, 1),
        "server_other_us": round(server_other, 1),
        "floor_us_per_query": round(floor, 1),
        "floor_us_per_decision": round(floor / arenas, 1),
        "cpu_ratio_bound": round(decision / (decision + floor / arenas), 3),
    }


def measure(pings: int) -> list[dict[str, object]]:
    """Every floor: first a query (what ``RM`` sends) to a sleeping and to a polling server,
    the ones ``bench_transport``'s bounds use."""
    return [zenoh_rtt(pings), zenoh_rtt(pings, poll=True), pubsub_rtt(pings), tcp_rtt(pings)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    arenas = between(0, MAX_ARENAS)
    parser.add_argument("--pings", type=at_least(1), default=3000)
    parser.add_argument("--arenas", type=arenas, default=8, help="K of the vector floor (0: skip)")
    parser.add_argument(
        "--held-pings", type=at_least(1), default=200, help="queries of the vector floor"
    )
    parser.add_argument("--serve", choices=[*sorted(SERVERS), "zenoh-held"], help=argparse.SUPPRESS)
    parser.add_argument("--port", type=tcp_port, help=argparse.SUPPRESS)
    parser.add_argument("--hold-ms", type=non_negative, default=0.0, help=argparse.SUPPRESS)
    parser.add_argument("--reply-bytes", type=at_least(0), default=1, help=argparse.SUPPRESS)
    parser.add_argument("--hold-arenas", type=arenas, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve and args.port is None:
        parser.error("--serve needs --port")
    if args.serve:
        # SIGTERM as SystemExit, so the server's ``finally`` closes its session.
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
        if args.serve == "zenoh-held":
            serve_zenoh(
                args.port,
                hold_s=args.hold_ms / 1e3,
                reply_bytes=args.reply_bytes,
                hold_arenas=args.hold_arenas,
            )
        else:
            SERVERS[args.serve](args.port)
        return
    rows = measure(args.pings)
    print(table(rows, ["path", "pings", "median_us", "p99_us"]))
    held = [held_floor(args.held_pings, args.arenas, hold=h) for h in HOLDS if args.arenas > 0]
    if held:
        print("The vector path's floor (CPU µs, all threads of both processes, less the hold):")
        print(table(held, list(held[0])))
    report = {
        "results": rows,
        "vector_floor": held[0] if held else None,
        "vector_floor_arenas": held[1] if held else None,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('zenoh_floor', report)}")


if __name__ == "__main__":
    main()
