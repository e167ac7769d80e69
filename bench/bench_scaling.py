"""Sampling throughput with 1, 2, 4 and 8 servers on one machine, and a cluster projection.

    python -m bench.bench_scaling [--counts 1 2 4 8] [--envs 8] [--seconds 8] [--repeats 3]

Starts the largest number of servers once with the fleet supervisor (``neuronsmae-fleet``'s
:class:`~neuronsmae.server.serving.supervisor.Fleet`, unpaced: ``time_scale=0``), each
holding ``--envs`` arenas (``--arenas``; 1 measures the one-query-per-decision path). For
each count ``n`` and each repeat, ``n`` client processes (spawned, one per server, like
rollout workers) open ``VecRM(port=..., num_envs=envs, launch=False)`` on the training task
(abstract actions, cooperative 2 v 2), warm up, meet at a barrier, then play random
allowed actions in every arena for ``--seconds``; a decision is one arena advancing once.
The aggregate rate is the sum of the clients' decisions/s; the table reports
the median over repeats, with the CPU seconds that servers and clients spent per decision
(psutil for the servers, ``process_time`` for the clients) and the load average.

The projection to 20-25 workers assumes what a cluster gives and this machine does not: a
core per (worker, server) pair on the worker's node, so each pair runs at the rate its own
CPU cost allows (1 / CPU-seconds per decision, measured here); it is a projection, not a
measurement. Writes bench/out/scaling.json.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import statistics
import tempfile
import time
from multiprocessing.synchronize import Barrier
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from bench.common import (
    MAX_PORT,
    Distinct,
    arena_count,
    at_least,
    machine,
    positive,
    process_cpu_seconds,
    table,
    tcp_port,
    write_json,
)
from neuronsmae.client import VecRM
from neuronsmae.server.serving.rpc import PortInUseError, check_port
from neuronsmae.server.serving.supervisor import Fleet, FleetSpec

OPTIONS: dict[str, Any] = {
    "action_space": "abstract",
    "n_blue": 2,
    "n_red": 2,
    "mode": "cooperative",
}
"""The task the trainers sample (``trainers.rollout.DEFAULT_ENV_OPTIONS``)."""
WARMUP_DECISIONS = 10
PROJECT_TO = (20, 25)


def drive(port: int, envs: int, seed: int, seconds: float, barrier: Barrier, out: Any) -> None:
    """One client process: random allowed actions in its server's arenas for ``seconds``."""
    rng = np.random.default_rng(seed)
    env = VecRM(seed=seed, port=port, num_envs=envs, launch=False, timeout=60.0, **OPTIONS)
    try:

        def step() -> None:
            avail = env.get_avail_actions()
            env.step((avail * rng.random(avail.shape)).argmax(-1))  # arenas autoreset

        env.reset()
        for _ in range(WARMUP_DECISIONS):
            step()
        barrier.wait()
        done, cpu, start = 0, time.process_time(), time.perf_counter()
        while time.perf_counter() - start < seconds:
            step()
            done += envs
        wall = time.perf_counter() - start
        out.put({"port": port, "decisions": done, "wall": wall, "cpu": time.process_time() - cpu})
    finally:
        env.close()


def one_round(ports: list[int], envs: int, seconds: float, seed: int) -> dict[str, Any]:
    """All clients at once, started together; aggregate rate and CPU per decision."""
    ctx = mp.get_context("spawn")  # never fork: this process and the clients use Zenoh
    barrier, out = ctx.Barrier(len(ports) + 1), ctx.Queue()
    clients = [
        ctx.Process(
            target=drive, args=(port, envs, seed + i * envs, seconds, barrier, out), daemon=True
        )
        for i, port in enumerate(ports)
    ]
    for client in clients:
        client.start()
    servers = [p for p in psutil.Process().children() if _serves(p, ports)]
    barrier.wait(timeout=300)
    load, server_cpu = os.getloadavg()[0], process_cpu_seconds(servers)
    results = [out.get(timeout=seconds + 120) for _ in clients]
    server_cpu = process_cpu_seconds(servers) - server_cpu
    for client in clients:
        client.join(30)
    decisions = sum(r["decisions"] for r in results)
    return {
        "rate": sum(r["decisions"] / r["wall"] for r in results),
        "per_client": [round(r["decisions"] / r["wall"], 1) for r in results],
        "cpu_per_decision": (server_cpu + sum(r["cpu"] for r in results)) / max(decisions, 1),
        "load1": load,
    }


def _serves(proc: psutil.Process, ports: list[int]) -> bool:
    try:
        cmd = proc.cmdline()
    except psutil.Error:
        return False
    return "neuronsmae.server" in cmd and any(str(p) in cmd for p in ports)


def measure(
    counts: list[int], envs: int, seconds: float, repeats: int, base_port: int
) -> list[dict]:
    spec = FleetSpec(base_port=base_port, count=max(counts), seed=1, time_scale=0.0, arenas=envs)
    rows = []
    with tempfile.TemporaryDirectory() as tmp, Fleet(spec, Path(tmp), Path(tmp) / "s.json") as f:
        f.start()
        if not all(h.up for h in f.check()):
            raise RuntimeError("not every server answers; see the logs in " + tmp)
        for n in counts:
            rounds = [one_round(spec.ports()[:n], envs, seconds, 100 * r) for r in range(repeats)]
            rates = [r["rate"] for r in rounds]
            cpu = statistics.median(r["cpu_per_decision"] for r in rounds)
            rows.append(
                {
                    "servers": n,
                    "envs_per_server": envs,
                    "decisions_per_s": round(statistics.median(rates), 1),
                    "min": round(min(rates), 1),
                    "max": round(max(rates), 1),
                    "per_server": round(statistics.median(rates) / n, 1),
                    "cpu_ms_per_decision": round(cpu * 1000, 2),
                    "load1": round(statistics.median(r["load1"] for r in rounds), 2),
                    "rounds": rounds,
                }
            )
            print(f"{n} servers: {rows[-1]['decisions_per_s']} decisions/s", flush=True)
    return rows


def projection(rows: list[dict]) -> list[dict]:
    """Decisions/s for 20-25 pairs with a core each, from the measured CPU per decision."""
    cpu_s = statistics.median(r["cpu_ms_per_decision"] for r in rows) / 1000
    single = rows[0]["decisions_per_s"] if rows[0]["servers"] == 1 else None
    out = []
    for workers in PROJECT_TO:
        out.append(
            {
                "workers": workers,
                "cpu_bound_decisions_per_s": round(workers / cpu_s, 0),
                "at_measured_single_rate": round(workers * single, 0) if single else None,
            }
        )
    return out


def check_ports(parser: argparse.ArgumentParser, base_port: int, counts: list[int]) -> None:
    """Refuse a fleet whose last port, ``base_port + max(counts) - 1``, is past the last,
    or one of whose ports something already listens on (checked now, not when that
    fleet starts, minutes into the run)."""
    if not counts:
        return
    if base_port + max(counts) - 1 > MAX_PORT:
        parser.error(
            f"--base-port {base_port} with --counts up to {max(counts)} puts servers past "
            f"port {MAX_PORT}"
        )
    for port in range(base_port, base_port + max(counts)):
        try:
            check_port("127.0.0.1", port)
        except PortInUseError as exc:
            parser.error(f"--base-port {base_port}: {exc}; pick another --base-port")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--counts", type=at_least(1), nargs="+", action=Distinct, default=[1, 2, 4, 8]
    )
    parser.add_argument("--envs", type=arena_count, default=8, help="arenas per server (8)")
    parser.add_argument("--seconds", type=positive, default=8.0)
    parser.add_argument("--repeats", type=at_least(1), default=3)
    parser.add_argument("--base-port", type=tcp_port, default=18000)
    args = parser.parse_args()
    check_ports(parser, args.base_port, args.counts)
    load_before = os.getloadavg()
    rows = measure(sorted(args.counts), args.envs, args.seconds, args.repeats, args.base_port)
    proj = projection(rows)
    columns = ["servers", "envs_per_server", "decisions_per_s", "min", "max", "per_server"]
    columns += ["cpu_ms_per_decision", "load1"]
    print(table(rows, columns))
    print(table(proj, ["workers", "cpu_bound_decisions_per_s", "at_measured_single_rate"]))
    print(f"load average before: {load_before[0]:.2f} {load_before[1]:.2f} {load_before[2]:.2f}")
    report = {
        "options": OPTIONS,
        "seconds": args.seconds,
        "repeats": args.repeats,
        "results": rows,
        "projection": proj,
        "load_before": load_before,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('scaling', report)}")


if __name__ == "__main__":
    main()
