"""The served vector path against the in-process one: CPU and speed per decision, memory.

    python -m bench.bench_vector [--envs 1 4 8 16] [--steps 40] [--rounds 21]

For each K, K arenas served by one ``neuronsmae-server --arenas K`` (reached through a
``VecRM``, unpaced) and K arenas in this process (a ``VecArena``) play the same loop: read
the masks, pick a random available action for every agent of every arena (one vectorised
draw), ``step``; arenas autoreset. Rounds alternate between the two (and between the Ks),
so load from other processes hits them alike. Reported per K, as medians over rounds:

* CPU µs per decision (one decision = one arena advancing once): for the served path the
  client process and the server process together, all their threads, each read to the
  nanosecond from the scheduler (``bench.common.cpu_snapshot``); the ratio
  in-process / served of those (**target ≥ 0.9 at K = 8**), and the ratio of decisions per
  second. Both ratios are medians of per-round ratios: a round plays the in-process and
  the served arenas back to back from the same state with the same actions (the same
  simulation work), so a shared VM's slow drifts cancel within each pair; the interquartile
  range of the per-round CPU ratios shows how noisy the machine was;
* CPU by thread (client main / other, server main / other);
* resident memory of the server per arena, idle after the first reset and after playing
  (**target ≤ 60 MB per arena at K = 8**).

Then, in the same run, the one-arena ping-pong as ``bench_transport`` measures it (``RM``
against ``Arena``, one query per decision). Prints Markdown tables and writes
bench/out/vector.json.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import psutil

from bench.bench_transport import compare
from bench.common import (
    Distinct,
    arena_count,
    at_least,
    cpu_between,
    cpu_by_thread,
    cpu_snapshot,
    machine,
    table,
    write_json,
)
from neuronsmae.client.vec_rm import VecRM
from neuronsmae.protocol.interface import VecArenaAPI
from neuronsmae.server.vec import VecArena

CPU_TARGET = 0.9
MEMORY_TARGET_MB = 60.0
TARGET_K = 8


def play(env: VecArenaAPI, steps: int, rng: np.random.Generator) -> None:
    """``steps`` vector steps with random available actions (every arena, every agent)."""
    avail = env.get_avail_actions()
    for _ in range(steps):
        actions = (avail * rng.random(avail.shape)).argmax(-1)
        env.step(actions)
        avail = env.get_avail_actions()


def measure(
    env: VecArenaAPI, steps: int, seed: int, procs: list[psutil.Process]
) -> tuple[float, float, np.ndarray]:
    """Decisions per second, CPU µs per decision of ``procs``, and per-thread CPU µs per
    decision ``[process][main, other]`` of one round."""
    before, wall = cpu_snapshot(procs), time.perf_counter()
    play(env, steps, np.random.default_rng(seed))
    wall, after = time.perf_counter() - wall, cpu_snapshot(procs)
    decisions = steps * env.num_envs
    threads = np.array(cpu_by_thread(before, after, [p.pid for p in procs]))
    return decisions / wall, cpu_between(before, after) / decisions * 1e6, threads / decisions * 1e6


def rss_mb(proc: psutil.Process) -> float:
    return proc.memory_info().rss / 2**20


def run(envs: list[int], steps: int, rounds: int) -> list[dict[str, Any]]:
    """Build every pair, then play interleaved rounds; one result row per K."""
    me = psutil.Process()
    pairs: dict[int, tuple[VecArena, VecRM, psutil.Process, float]] = {}
    try:
        for k in envs:
            local = VecArena(seed=1, num_envs=k)
            remote = VecRM(seed=1, num_envs=k)
            server = remote._conns[0].server
            assert server is not None
            proc = psutil.Process(server.proc.pid)
            local.reset()
            remote.reset()
            pairs[k] = (local, remote, proc, rss_mb(proc))
            play(local, 3, np.random.default_rng(0))  # warm both up
            play(remote, 3, np.random.default_rng(0))
        runs: dict[int, dict[str, list[Any]]] = {k: {"in_process": [], "served": []} for k in envs}
        for r in range(rounds):
            for k, (local, remote, proc, _) in pairs.items():
                n = max(4, steps * 8 // k)  # about the same decisions per round for every K
                runs[k]["in_process"].append(measure(local, n, 100 * r + k, [me, proc]))
                runs[k]["served"].append(measure(remote, n, 100 * r + k, [me, proc]))
        return [_row(k, runs[k], pairs[k][3], rss_mb(pairs[k][2])) for k in envs]
    finally:
        for local, remote, _, _ in pairs.values():
            remote.close()
            local.close()


def _row(k: int, runs: dict[str, list[Any]], idle_mb: float, played_mb: float) -> dict[str, Any]:
    local, served = runs["in_process"], runs["served"]
    cpu_in = statistics.median(c for _, c, _ in local)
    cpu_served = statistics.median(c for _, c, _ in served)
    cpu_pairs = [p[1] / s[1] for p, s in zip(local, served, strict=True)]
    q1, _, q3 = statistics.quantiles(cpu_pairs, n=4) if len(cpu_pairs) > 1 else [cpu_pairs[0]] * 3
    threads = np.median([t for _, _, t in served], axis=0)  # µs per decision
    per = {
        f"{who}_{part}": round(float(threads[i, j]), 1)
        for i, who in enumerate(("client", "server"))
        for j, part in enumerate(("main", "other"))
    }
    return {
        "envs": k,
        "in_process_decisions_per_s": round(statistics.median(r for r, _, _ in local), 1),
        "served_decisions_per_s": round(statistics.median(r for r, _, _ in served), 1),
        "speed_ratio": round(
            statistics.median(s[0] / p[0] for p, s in zip(local, served, strict=True)), 3
        ),
        "in_process_cpu_us": round(cpu_in, 1),
        "served_cpu_us": round(cpu_served, 1),
        "cpu_ratio": round(statistics.median(cpu_pairs), 3),
        "cpu_ratio_iqr": [round(q1, 3), round(q3, 3)],
        "served_cpu_us_by_thread": per,
        "server_rss_mb_per_arena_idle": round(idle_mb / k, 1),
        "server_rss_mb_per_arena_played": round(played_mb / k, 1),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--envs", type=arena_count, nargs="+", action=Distinct, default=[1, 4, 8, 16]
    )
    parser.add_argument(
        "--steps", type=at_least(1), default=40, help="vector steps per round at K=8"
    )
    parser.add_argument("--rounds", type=at_least(1), default=21)
    parser.add_argument(
        "--pingpong-decisions", type=at_least(0), default=150, help="0: no ping-pong"
    )
    args = parser.parse_args()
    rows = run(args.envs, args.steps, args.rounds)
    pingpong = None
    if args.pingpong_decisions:
        pingpong = compare(
            "abstract 2v2",
            {"action_space": "abstract", "n_blue": 2, "n_red": 2},
            args.pingpong_decisions,
            args.rounds,
        )
    print(
        table(
            rows,
            [
                "envs",
                "in_process_decisions_per_s",
                "served_decisions_per_s",
                "speed_ratio",
                "in_process_cpu_us",
                "served_cpu_us",
                "cpu_ratio",
                "cpu_ratio_iqr",
                "server_rss_mb_per_arena_idle",
                "server_rss_mb_per_arena_played",
            ],
        )
    )
    shares = [{"envs": r["envs"], **r["served_cpu_us_by_thread"]} for r in rows]
    print("Served path, CPU µs per decision by thread (main: the arenas' or the client loop's):")
    print(table(shares, ["envs", "client_main", "client_other", "server_main", "server_other"]))
    at = next((r for r in rows if r["envs"] == TARGET_K), None)
    if at is not None:
        print(
            f"K = {TARGET_K}: CPU ratio {at['cpu_ratio']:.3f} (target ≥ {CPU_TARGET}); "
            f"{at['server_rss_mb_per_arena_played']:.0f} MB per served arena "
            f"(target ≤ {MEMORY_TARGET_MB:.0f})"
        )
    if pingpong is not None:
        print(
            f"one arena, one query per decision (RM against Arena): speed ratio "
            f"{pingpong['ratio']:.3f}, CPU ratio {pingpong['cpu_ratio']:.3f}"
        )
    report = {
        "steps_per_round_at_8": args.steps,
        "rounds": args.rounds,
        "targets": {"cpu_ratio_at_8": CPU_TARGET, "rss_mb_per_arena_at_8": MEMORY_TARGET_MB},
        "rows": rows,
        "one_arena_pingpong": pingpong,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('vector', report)}")


if __name__ == "__main__":
    main()
