"""Transport overhead: decisions/s over Zenoh (RM) against the in-process Arena, same run.

    python -m bench.bench_transport [--decisions 150] [--rounds 7] [--pings 2000]

For each configuration both arenas play the same trainer-like loop (``get_avail_actions``,
pick random allowed actions, ``step``, ``reset`` when done) for ``--decisions`` decisions,
alternating in-process and remote rounds so load from other processes on the machine hits
both alike; the median round rate of each is reported, and the median of the paired
(remote / in-process) round ratios. The server is launched by ``RM`` on a
free loopback port with ``time_scale=0`` (unpaced). Also measures the round trip of a
``ping`` (median and p99), and the floor of any query (``bench.zenoh_floor``: a bare Zenoh
query and a bare TCP socket, nothing of NeuronsMAE in either), from which ``bound_ratio``
is the ratio a free server and client would reach. Prints a Markdown table and writes
bench/out/transport.json.

``--busy-poll-us`` adds rows for servers that poll for their next request that long after
each reply (``neuronsmae-server --busy-poll``) instead of sleeping at once.

Per-thread CPU time per decision (client and server, main thread and the rest) shows where
the Zenoh path's extra cost lands: the server's main thread runs the arena and the codec,
the other threads are mostly Zenoh's runtime.

Wall-clock rates are what a trainer sees, but on a loaded machine they favour the remote
pair (two processes that sleep in turn get more of a contended CPU than one busy process).
The CPU-time rates (decisions per CPU second of the bench process, plus the server's for
Zenoh) measure the transport's real cost whatever else runs.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import psutil

from bench.common import (
    Distinct,
    at_least,
    cpu_between,
    cpu_by_thread,
    cpu_snapshot,
    finite,
    free_port,
    machine,
    table,
    write_json,
)
from bench.zenoh_floor import measure as measure_floor
from neuronsmae.client import RM
from neuronsmae.protocol.interface import ArenaAPI
from neuronsmae.protocol.link import Link
from neuronsmae.protocol.messages import Ping, encode_request
from neuronsmae.protocol.transport import MAX_BUSY_POLL_US
from neuronsmae.server.arena import Arena

CONFIGS: dict[str, dict[str, Any]] = {
    "abstract 2v2": {"action_space": "abstract", "n_blue": 2, "n_red": 2},
    "continuous 2v2": {"action_space": "continuous", "n_blue": 2, "n_red": 2},
}
TARGET = 0.85


def play(
    env: ArenaAPI,
    decisions: int,
    rng: np.random.Generator,
    continuous: bool,
    procs: list[psutil.Process],
) -> tuple[float, float]:
    """Decisions per wall-clock second and per CPU second (of ``procs``) of a trainer-like
    loop on ``env``."""
    env.reset()
    wall, cpu = time.perf_counter(), cpu_snapshot(procs)
    for _ in range(decisions):
        actions: list[Any] = []
        for mask in env.get_avail_actions():
            choice = int(rng.choice(np.flatnonzero(mask)))
            actions.append([*rng.uniform(-1.5, 1.5, 3).tolist(), choice] if continuous else choice)
        if env.step(actions)[2]:
            env.reset()
    wall, used = time.perf_counter() - wall, cpu_between(cpu, cpu_snapshot(procs))
    return decisions / wall, decisions / max(used, 1e-9)


def launched_server(port: int) -> psutil.Process:
    """The server process RM launched on ``port`` (a child of this process)."""
    for child in psutil.Process().children():
        if "neuronsmae.server" in child.cmdline() and str(port) in child.cmdline():
            return child
    raise RuntimeError(f"no launched server on port {port}")


def _summary(local: list[float], remote: list[float]) -> tuple[float, float, float]:
    """Medians of both, and the median of the paired ratios: each remote round runs right
    after its in-process twin (same actions, same episodes), so paired ratios are the least
    disturbed by other load on the machine."""
    ratios = [r / p for p, r in zip(local, remote, strict=True)]
    return statistics.median(local), statistics.median(remote), statistics.median(ratios)


def compare(
    name: str, options: dict[str, Any], decisions: int, rounds: int, busy_poll_us: float = 0.0
) -> dict[str, Any]:
    continuous = options["action_space"] == "continuous"
    port = free_port()
    local = Arena(seed=1, **options)
    remote = RM(seed=1, port=port, time_scale=0, busy_poll_us=busy_poll_us, **options)
    me = [psutil.Process()]
    both = [*me, launched_server(port)]
    try:
        play(local, 5, np.random.default_rng(0), continuous, me)  # warm both up
        play(remote, 5, np.random.default_rng(0), continuous, both)
        runs: dict[str, list[tuple[float, float]]] = {"in_process": [], "zenoh": []}
        threads = np.zeros((2, 2, 2))  # [in process / zenoh][client / server][main / other]
        for r in range(rounds):
            for k, (path, env, procs) in enumerate(
                (("in_process", local, me), ("zenoh", remote, both))
            ):
                before = cpu_snapshot(both)
                runs[path].append(play(env, decisions, np.random.default_rng(r), continuous, procs))
                threads[k] += cpu_by_thread(before, cpu_snapshot(both), [p.pid for p in both])
    finally:
        remote.close()
        local.close()
    wall = _summary(*([w for w, _ in runs[k]] for k in ("in_process", "zenoh")))
    cpu = _summary(*([c for _, c in runs[k]] for k in ("in_process", "zenoh")))
    return {
        "config": name,
        "busy_poll_us": busy_poll_us,
        "options": options,
        "in_process_decisions_per_s": round(wall[0], 1),
        "zenoh_decisions_per_s": round(wall[1], 1),
        "ratio": round(wall[2], 3),
        "in_process_decisions_per_cpu_s": round(cpu[0], 1),
        "zenoh_decisions_per_cpu_s": round(cpu[1], 1),
        "cpu_ratio": round(cpu[2], 3),
        "cpu_us_per_decision": {
            side: {
                f"{who}_{part}": round(float(threads[k, i, j]) / (rounds * decisions) * 1e6, 1)
                for i, who in enumerate(("client", "server"))
                for j, part in enumerate(("main", "other"))
                if not (side == "in_process" and who == "server")
            }
            for k, side in enumerate(("in_process", "zenoh"))
        },
        "rounds": {k: [[round(w, 1), round(c, 1)] for w, c in v] for k, v in runs.items()},
    }


def ping_rtt(pings: int) -> dict[str, float]:
    """Round trip of an empty request through the full stack (encode, Zenoh, decode)."""
    port = free_port()
    with RM(port=port, time_scale=0):  # launches the server; the link below only pings it
        link = Link("127.0.0.1", port)
        try:
            payload = encode_request(Ping(), "bench")
            for _ in range(50):
                link.call(payload, 2.0)
            times = []
            for _ in range(pings):
                start = time.perf_counter()
                link.call(payload, 2.0)
                times.append(time.perf_counter() - start)
        finally:
            link.close()
    times.sort()
    return {
        "pings": pings,
        "median_us": round(statistics.median(times) * 1e6, 1),
        "p99_us": round(times[int(0.99 * (len(times) - 1))] * 1e6, 1),
    }


def bound(in_process_per_s: float, floor_us: float) -> float:
    """The highest ratio one Zenoh query per decision allows, were the server and the
    client free: an in-process decision against itself plus a bare query's round trip."""
    decision_us = 1e6 / in_process_per_s
    return round(decision_us / (decision_us + floor_us), 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--decisions", type=at_least(1), default=150)
    parser.add_argument("--rounds", type=at_least(1), default=7)
    parser.add_argument("--pings", type=at_least(1), default=2000)
    parser.add_argument(
        "--busy-poll-us",
        type=finite(0.0, MAX_BUSY_POLL_US),
        nargs="*",
        action=Distinct,
        default=[2000.0],
        help="also measure servers that poll this many µs for the next request (2000); "
        "the plain server (0) is always measured",
    )
    args = parser.parse_args()
    results = [
        compare(n, o, args.decisions, args.rounds, busy)
        for busy in [0.0, *args.busy_poll_us]
        for n, o in CONFIGS.items()
    ]
    rtt = ping_rtt(args.pings)
    floor = measure_floor(args.pings)
    floor_us = {row["path"]: row["median_us"] for row in floor}
    for r in results:
        path = "zenoh query, server polling" if r["busy_poll_us"] else "zenoh query"
        r["bound_ratio"] = bound(r["in_process_decisions_per_s"], floor_us[path])
    columns = [
        "config",
        "busy_poll_us",
        "in_process_decisions_per_s",
        "zenoh_decisions_per_s",
        "ratio",
        "in_process_decisions_per_cpu_s",
        "zenoh_decisions_per_cpu_s",
        "cpu_ratio",
        "bound_ratio",
    ]
    print(table(results, columns))
    cpu_rows = [
        {
            "config": r["config"],
            "busy_poll_us": r["busy_poll_us"],
            "path": side,
            **r["cpu_us_per_decision"][side],
        }
        for r in results
        for side in ("in_process", "zenoh")
    ]
    print("CPU µs per decision by thread (main = the arena's or the client loop's):")
    parts = ["client_main", "client_other", "server_main", "server_other"]
    print(table(cpu_rows, ["config", "busy_poll_us", "path", *parts]))
    print(f"target: zenoh ≥ {TARGET:.0%} of in-process")
    print(f"ping round trip: median {rtt['median_us']:.0f} µs, p99 {rtt['p99_us']:.0f} µs")
    print("the floor, bare round trips without NeuronsMAE (bound_ratio uses the queries'):")
    print(table(floor, ["path", "pings", "median_us", "p99_us"]))
    report = {
        "decisions_per_round": args.decisions,
        "rounds": args.rounds,
        "target_ratio": TARGET,
        "results": results,
        "ping": rtt,
        "floor": floor,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('transport', report)}")


if __name__ == "__main__":
    main()
