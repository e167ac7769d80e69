"""Soak: one server, 100,000 decisions through the client, and five promises checked.

    python -m bench.soak [--decisions 100000] [--warmup 1000] [--envs 1] [--action-space discrete]

One ``neuronsmae-server`` (unpaced, ``--time-scale 0``, ``--arenas`` ``--envs``) on a free
loopback port and one client in this process (``RM`` for one arena, ``VecRM`` for several:
one request steps them all, finished arenas reset themselves) play random allowed actions.
A decision is one arena advancing once. After ``--warmup`` decisions the baseline is taken;
then, at the end:

1. the server's resident memory grew by less than 5 % over the baseline;
2. neither process leaks: the server's and the client's open file descriptors and inet
   connections (psutil) are no more at the end than at the baseline;
3. latency does not degrade: the p99 of every window of ``--window`` decisions is within
   2 × the p99 of the first thousand requests after warm-up (a request is one decision of
   every arena on the server);
4. cost does not creep: the CPU time per decision of the server and client processes
   together, in the last window, is within 1.15 × that of the first (a slow leak of work,
   such as a list walked every step, shows here long before it shows in latency);
5. rebuilds do not pile up memory: a fresh server reconfigured ``--rebuilds`` times (a new
   client each time, seeds alternating, one reset each) ends within 1.25 × its resident
   memory after the first configure.

Prints a table per window and writes bench/out/soak.json (``soak_vec<K>.json`` for
``--envs K`` > 1); exits 1 if a promise broke.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from typing import Any

import numpy as np
import psutil

from bench.common import (
    MAX_ARENAS,
    arena_count,
    at_least,
    free_port,
    machine,
    process_cpu_seconds,
    start_server,
    table,
    write_json,
)
from neuronsmae.client import RM, VecRM

RSS_GROWTH_LIMIT = 0.05
P99_FACTOR = 2.0
CPU_CREEP_LIMIT = 1.15
REBUILD_RSS_LIMIT = 1.25


def resources(proc: psutil.Process) -> dict[str, int]:
    """What a leak would grow: resident memory, file descriptors, inet connections."""
    return {
        "rss": proc.memory_info().rss,
        "fds": proc.num_fds(),
        "conns": len(proc.net_connections(kind="inet")),
    }


def _client(port: int, envs: int, seed: int, **options: Any) -> Any:
    """The client for a server of ``envs`` arenas on ``port``: ``RM`` for one, else ``VecRM``
    (which plays the discrete default: ``options`` go to ``RM`` only)."""
    if envs > 1:
        return VecRM(seed=seed, port=port, num_envs=envs, launch=False, timeout=10.0)
    return RM(seed=seed, port=port, launch=False, timeout=10.0, **options)


class _Player:
    """Random allowed actions for one client; ``step`` returns the decisions it made."""

    def __init__(self, port: int, envs: int, action_space: str) -> None:
        self.vector = envs > 1
        self.env = _client(port, envs, 1, action_space=action_space)
        self.continuous = action_space == "continuous"
        self.rng = np.random.default_rng(0)
        self.episodes = 0

    def reset(self) -> None:
        self.env.reset()
        self.episodes += self.env.num_envs if self.vector else 1

    def actions(self) -> Any:
        avail = self.env.get_avail_actions()  # from the step's snapshot: no round trip
        if self.vector:
            return (avail * self.rng.random(avail.shape)).argmax(-1)
        out: list[Any] = []
        for mask in avail:
            choice = int(self.rng.choice(np.flatnonzero(mask)))
            extra = self.rng.uniform(-1.5, 1.5, 3).tolist() if self.continuous else []
            out.append([*extra, choice] if self.continuous else choice)
        return out

    def step(self, actions: Any) -> int:
        done = self.env.step(actions)[2]
        if self.vector:
            self.episodes += int(np.count_nonzero(done))  # each reset itself on this step
            return self.env.num_envs
        if done:
            self.reset()
        return 1


def soak(
    decisions: int, warmup: int, action_space: str, envs: int = 1, window: int = 10_000
) -> dict[str, Any]:
    """Play ``decisions`` decisions; latency per request, resources at the warm-up and the
    end, server RSS every 1000 decisions and CPU seconds at every window boundary."""
    port = free_port()
    server = start_server(port, arenas=envs)
    server_ps, client_ps = psutil.Process(server.proc.pid), psutil.Process()
    latency: list[tuple[int, float]] = []  # (decisions before the request, seconds)
    rss_series: list[tuple[int, int]] = []
    cpu_marks: list[tuple[int, float]] = []
    player = _Player(port, envs, action_space)
    try:
        player.reset()
        done_k, t_start = 0, time.perf_counter()
        base: dict[str, dict[str, int]] = {}
        while done_k < decisions:
            if not base and done_k >= warmup:
                base = {"server": resources(server_ps), "client": resources(client_ps)}
            if done_k >= warmup and (done_k - warmup) // window >= len(cpu_marks):
                cpu_marks.append((done_k, process_cpu_seconds([server_ps, client_ps])))
            if done_k // 1000 >= len(rss_series):
                rss_series.append((done_k, server_ps.memory_info().rss))
            chosen = player.actions()
            t0 = time.perf_counter()
            made = player.step(chosen)
            latency.append((done_k, time.perf_counter() - t0))
            done_k += made
        wall = time.perf_counter() - t_start
        cpu_marks.append((done_k, process_cpu_seconds([server_ps, client_ps])))
        end = {"server": resources(server_ps), "client": resources(client_ps)}
    finally:
        player.env.close()
        server.stop()
    return {
        "latency": latency,
        "base": base,
        "end": end,
        "rss_series": rss_series,
        "cpu_marks": cpu_marks,
        "episodes": player.episodes,
        "decisions": done_k,
        "wall_s": wall,
        "port": port,
    }


def rebuild_rss(envs: int, count: int) -> list[float]:
    """Server RSS (MiB) after the first configure and after each of ``count`` rebuilds."""
    port = free_port()
    server = start_server(port, arenas=envs, seed=1)
    proc, out = psutil.Process(server.proc.pid), []
    try:
        for i in range(count + 1):
            env = _client(port, envs, 1 + 100 * (i % 2))
            try:
                env.reset()
                out.append(proc.memory_info().rss / 2**20)
            finally:
                env.close()
    finally:
        server.stop()
    return out


def windows(run: dict[str, Any], warmup: int, window: int) -> list[dict[str, Any]]:
    """Per window of ``window`` decisions after the warm-up: request latency percentiles and
    the CPU µs per decision of the server and client together."""
    lat = np.array([s for k, s in run["latency"] if k >= warmup]) * 1000
    first = np.array([k for k, _ in run["latency"] if k >= warmup])
    marks = run["cpu_marks"]
    rows = []
    for i, ((k0, c0), (k1, c1)) in enumerate(itertools.pairwise(marks)):
        part = lat[(first >= k0) & (first < k1)]
        rows.append(
            {
                "window": i,
                "decisions": f"{k0}-{k1 - 1}",
                "n": k1 - k0,
                "p50_ms": float(np.percentile(part, 50)),
                "p99_ms": float(np.percentile(part, 99)),
                "max_ms": float(part.max()),
                "cpu_us_per_decision": (c1 - c0) / (k1 - k0) * 1e6,
            }
        )
    return rows


MIN_WINDOW = 500
"""Shortest window: its CPU, read in 10 ms clock ticks, must be more than a few ticks (a
window of 2 decisions read 0 and the creep ratio divided by it)."""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--decisions", type=at_least(1), default=100_000)
    parser.add_argument("--warmup", type=at_least(0), default=1000)
    parser.add_argument(
        "--window", type=at_least(MIN_WINDOW), default=10_000,
        help=f"decisions per window, ≥ {MIN_WINDOW} (CPU is read in 10 ms clock ticks)",
    )  # fmt: skip
    parser.add_argument(
        "--envs", type=arena_count, default=1, help=f"arenas on the server, in [1, {MAX_ARENAS}]"
    )
    parser.add_argument("--action-space", default="discrete", choices=["discrete", "continuous"])
    parser.add_argument(
        "--rebuilds", type=at_least(0), default=16, help="reconfigures of a fresh server"
    )
    args = parser.parse_args()
    if args.decisions < args.warmup + 2 * args.window:
        parser.error("--decisions must exceed --warmup by at least two windows")
    if args.envs > 1 and args.action_space != "discrete":
        parser.error("--envs > 1 plays the discrete action space only")
    load_before = psutil.getloadavg()
    run = soak(args.decisions, args.warmup, args.action_space, args.envs, args.window)
    first_1000 = [s for k, s in run["latency"] if k >= args.warmup][:1000]
    baseline = float(np.percentile(first_1000, 99) * 1000)
    rows = windows(run, args.warmup, args.window)
    rebuilt = rebuild_rss(args.envs, args.rebuilds)
    full = [r for r in rows if r["n"] >= args.window // 2]
    creep = full[-1]["cpu_us_per_decision"] / full[0]["cpu_us_per_decision"]
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
        "p99 within 2x of the first 1000 requests": worst_p99 <= P99_FACTOR * baseline,
        f"CPU per decision, last / first window <= {CPU_CREEP_LIMIT}": creep <= CPU_CREEP_LIMIT,
        f"RSS after {args.rebuilds} rebuilds <= {REBUILD_RSS_LIMIT} x after the first": (
            rebuilt[-1] <= REBUILD_RSS_LIMIT * rebuilt[0]
        ),
    }
    columns = ["window", "decisions", "p50_ms", "p99_ms", "max_ms", "cpu_us_per_decision"]
    print(table(rows, columns))
    rate = run["decisions"] / run["wall_s"]
    print(f"{run['decisions']} decisions ({args.envs} arena(s) per request), "
          f"{run['episodes']} episodes started in {run['wall_s']:.0f} s "
          f"({rate:.0f} decisions/s)")  # fmt: skip
    print(f"server RSS {base['server']['rss'] / 2**20:.1f} -> {end['server']['rss'] / 2**20:.1f} "
          f"MiB ({growth:+.2%}); first-1000-requests p99 {baseline:.2f} ms, worst window p99 "
          f"{worst_p99:.2f} ms; CPU per decision last / first window {creep:.3f}")  # fmt: skip
    print(f"rebuilds: server RSS {rebuilt[0]:.0f} MiB after the first configure, "
          f"{max(rebuilt):.0f} at most, {rebuilt[-1]:.0f} after {args.rebuilds}")  # fmt: skip
    for who in ("server", "client"):
        print(f"{who}: fds {base[who]['fds']} -> {end[who]['fds']}, "
              f"inet connections {base[who]['conns']} -> {end[who]['conns']}")  # fmt: skip
    for promise, kept in promises.items():
        print(f"{'KEPT  ' if kept else 'BROKEN'} {promise}")
    report = {
        "decisions": run["decisions"],
        "warmup": args.warmup,
        "envs": args.envs,
        "action_space": args.action_space,
        "decisions_per_s": rate,
        "episodes": run["episodes"],
        "wall_s": run["wall_s"],
        "server_rss_growth": growth,
        "cpu_creep": creep,
        "resources": {"after_warmup": base, "end": end},
        "leaks": leaks,
        "p99_first_1000_ms": baseline,
        "windows": rows,
        "rss_series": run["rss_series"],
        "rebuild_rss_mib": rebuilt,
        "promises": promises,
        "load_before": load_before,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    name = "soak" if args.envs == 1 else f"soak_vec{args.envs}"
    print(f"wrote {write_json(name, report)}")
    return 0 if all(promises.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
