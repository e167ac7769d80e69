"""Soak: one server, 100,000 decisions through the client, and three promises checked.

    python -m bench.soak [--decisions 100000] [--warmup 1000] [--action-space discrete]

One ``neuronsmae-server`` (unpaced, ``--time-scale 0``) on a free loopback port and one
``RM`` client in this process play random allowed actions, resetting when an episode ends.
After ``--warmup`` decisions the baseline is taken; then, at the end:

1. the server's resident memory grew by less than 5 % over the baseline;
2. neither process leaks: the server's and the client's open file descriptors and inet
   connections (psutil) are no more at the end than at the baseline;
3. latency does not degrade: the p99 of every later window of ``--window`` decisions is
   within 2 × the p99 of the first window after warm-up (the first thousand decisions).

Prints a table per window and writes bench/out/soak.json; exits 1 if a promise broke.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Any

import numpy as np
import psutil

from bench.common import machine, table, write_json
from neuronsmae.client import RM
from tests.client.conftest import Server, free_port

RSS_GROWTH_LIMIT = 0.05
P99_FACTOR = 2.0


def resources(proc: psutil.Process) -> dict[str, int]:
    """What a leak would grow: resident memory, file descriptors, inet connections."""
    return {
        "rss": proc.memory_info().rss,
        "fds": proc.num_fds(),
        "conns": len(proc.net_connections(kind="inet")),
    }


def soak(decisions: int, warmup: int, action_space: str) -> dict[str, Any]:
    port = free_port()
    server = Server(port, "--time-scale", "0").wait_ready()
    server_ps, client_ps = psutil.Process(server.proc.pid), psutil.Process()
    rng = np.random.default_rng(0)
    latency = np.zeros(decisions)
    rss_series: list[tuple[int, int]] = []
    env = RM(seed=1, port=port, launch=False, timeout=10.0, action_space=action_space)
    try:
        continuous = action_space == "continuous"

        def actions() -> list[Any]:
            out: list[Any] = []
            for mask in env.get_avail_actions():  # from the step's snapshot: no round trip
                choice = int(rng.choice(np.flatnonzero(mask)))
                out.append([*rng.uniform(-1.5, 1.5, 3).tolist(), choice] if continuous else choice)
            return out

        env.reset()
        episodes, t_start = 1, time.perf_counter()
        base: dict[str, dict[str, int]] = {}
        for k in range(decisions):
            if k == warmup:
                base = {"server": resources(server_ps), "client": resources(client_ps)}
            if k % 1000 == 0:
                rss_series.append((k, server_ps.memory_info().rss))
            chosen = actions()
            t0 = time.perf_counter()
            done = env.step(chosen)[2]
            latency[k] = time.perf_counter() - t0
            if done:
                env.reset()
                episodes += 1
        wall = time.perf_counter() - t_start
        end = {"server": resources(server_ps), "client": resources(client_ps)}
    finally:
        env.close()
        server.stop()
    return {
        "latency": latency,
        "base": base,
        "end": end,
        "rss_series": rss_series,
        "episodes": episodes,
        "wall_s": wall,
        "port": port,
    }


def windows(latency: np.ndarray, warmup: int, window: int) -> list[dict[str, Any]]:
    rows = []
    for start in range(warmup, len(latency), window):
        part = latency[start : start + window] * 1000
        rows.append(
            {
                "decisions": f"{start}-{start + len(part) - 1}",
                "p50_ms": float(np.percentile(part, 50)),
                "p99_ms": float(np.percentile(part, 99)),
                "max_ms": float(part.max()),
            }
        )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--decisions", type=int, default=100_000)
    parser.add_argument("--warmup", type=int, default=1000)
    parser.add_argument("--window", type=int, default=10_000, help="decisions per p99 window")
    parser.add_argument("--action-space", default="discrete", choices=["discrete", "continuous"])
    args = parser.parse_args()
    if args.decisions < args.warmup + 2000:
        parser.error("--decisions must exceed --warmup by at least 2000")
    load_before = psutil.getloadavg()
    run = soak(args.decisions, args.warmup, args.action_space)
    baseline = float(np.percentile(run["latency"][args.warmup : args.warmup + 1000], 99) * 1000)
    rows = windows(run["latency"], args.warmup, args.window)
    base, end = run["base"], run["end"]
    growth = end["server"]["rss"] / base["server"]["rss"] - 1
    leaks = {
        f"{who}.{what}": (base[who][what], end[who][what])
        for who in ("server", "client")
        for what in ("fds", "conns")
        if end[who][what] > base[who][what]
    }
    worst_p99 = max(r["p99_ms"] for r in rows)
    promises = {
        "server RSS growth < 5%": growth < RSS_GROWTH_LIMIT,
        "no fd or connection leak": not leaks,
        "p99 within 2x of the first 1000": worst_p99 <= P99_FACTOR * baseline,
    }
    print(table(rows, ["decisions", "p50_ms", "p99_ms", "max_ms"]))
    rate = args.decisions / run["wall_s"]
    print(f"{args.decisions} decisions, {run['episodes']} episodes in {run['wall_s']:.0f} s "
          f"({rate:.0f} decisions/s)")  # fmt: skip
    print(f"server RSS {base['server']['rss'] / 2**20:.1f} -> {end['server']['rss'] / 2**20:.1f} "
          f"MiB ({growth:+.2%}); first-1000 p99 {baseline:.2f} ms, worst window p99 "
          f"{worst_p99:.2f} ms")  # fmt: skip
    for who in ("server", "client"):
        print(f"{who}: fds {base[who]['fds']} -> {end[who]['fds']}, "
              f"inet connections {base[who]['conns']} -> {end[who]['conns']}")  # fmt: skip
    for promise, kept in promises.items():
        print(f"{'KEPT  ' if kept else 'BROKEN'} {promise}")
    report = {
        "decisions": args.decisions,
        "warmup": args.warmup,
        "action_space": args.action_space,
        "decisions_per_s": rate,
        "episodes": run["episodes"],
        "wall_s": run["wall_s"],
        "server_rss_growth": growth,
        "resources": {"after_warmup": base, "end": end},
        "leaks": leaks,
        "p99_first_1000_ms": baseline,
        "windows": rows,
        "rss_series": run["rss_series"],
        "promises": promises,
        "load_before": load_before,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('soak', report)}")
    return 0 if all(promises.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
