"""Ray sampling throughput: the trainers' rollout workers against the in-process rate.

    python -m bench.bench_sampling [--workers 1 2 4] [--seconds 20] [--repeats 3] [--env inprocess]

What a learner sees: env steps per second of *finished episodes* returned by the
``Sampler`` (the same Ray actors, ε-greedy GRU policy, feature code and episode packing that
training uses, ``pipeline`` requests in flight per worker), for each worker count. Beside it,
in the same run, the in-process rate: one ``RolloutWorker`` (the plain class, no Ray)
playing episodes in this process. Both use an untrained agent network (acting costs the
same whatever the weights) at ε = 0.2 against the easy bot.

Rounds alternate between the in-process loop and every worker count, so load from other
processes hits them alike; each figure is the median over ``--repeats`` rounds. The ratio
column is the median of the paired (Ray / in-process) round ratios. Learning is not
included (the learner would compete for the same cores); docs/results.md reports the
steps/s of whole training runs. Prints a Markdown table and writes
bench/out/sampling.json.
"""

from __future__ import annotations

import argparse
import logging
import math
import statistics
import time
from typing import Any

import ray

from bench.common import machine, table, write_json
from neuronsmae.protocol import EnvInfo
from neuronsmae.trainers.learner import EnvSpec, agent_spec
from neuronsmae.trainers.rollout import Policy, RolloutWorker
from neuronsmae.trainers.sampler import Request, Sampler

CONTEXTS = {"level": "easy"}
EPSILON = 0.2


def make_policy(info: dict[str, Any]) -> Policy:
    """An untrained agent of the default architecture, as the trainer would broadcast."""
    layout = EnvInfo.from_dict(info)
    env = EnvSpec.of(layout, "relative")
    spec = agent_spec(env, 128, True, True, "relative", "points", layout)
    weights = {k: v.detach().numpy().copy() for k, v in spec.build().state_dict().items()}
    return Policy(spec, weights)


def in_process_round(worker: RolloutWorker, policy: Policy, seconds: float, seed: int) -> float:
    """Env steps per second of whole episodes played in this process for ``seconds``."""
    steps, start, k = 0, time.perf_counter(), 0
    while time.perf_counter() - start < seconds:
        steps += worker.run_episode(policy, 0, EPSILON, seed + k, CONTEXTS).obs.shape[0] - 1
        k += 1
    return steps / (time.perf_counter() - start)


def ray_round(sampler: Sampler, seconds: float, seed: int) -> float:
    """Env steps per second of the episodes that landed within ``seconds``.

    The pipeline is filled first and kept full; only episodes that finish inside the window
    count, and the window ends at the last landing, so a half-played episode is never
    credited.
    """
    k = 0
    while sampler.idle_slots() > 0:
        sampler.submit(Request(seed + k, EPSILON))
        k += 1
    steps, start, last = 0, time.perf_counter(), time.perf_counter()
    while time.perf_counter() - start < seconds:
        for episode in sampler.wait():
            steps += episode.obs.shape[0] - 1
            last = time.perf_counter()
        while sampler.idle_slots() > 0:
            sampler.submit(Request(seed + k, EPSILON))
            k += 1
    sampler.wait()  # let in-flight episodes land before the next round
    while sampler.in_flight:
        sampler.wait()
    return steps / max(last - start, 1e-9)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4])
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--env", choices=["inprocess", "remote"], default="inprocess")
    parser.add_argument("--worker-cpus", type=float, default=0.5)
    parser.add_argument("--base-port", type=int, default=12000)
    args = parser.parse_args()

    # Every sampler's actors live at once (rounds interleave), so Ray must be told there
    # are enough CPUs for all of them; they still share the machine's real cores.
    cpus = math.ceil(sum(args.workers) * args.worker_cpus) + 1
    ray.init(
        num_cpus=cpus, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False
    )
    local = RolloutWorker(0, "inprocess", 1, args.base_port - 1)
    policy = make_policy(local.env_info())
    samplers: dict[int, Sampler] = {}
    try:
        for n in args.workers:
            samplers[n] = Sampler(
                n,
                env_kind=args.env,
                base_seed=1000,
                base_port=args.base_port + 100 * n,
                contexts=CONTEXTS,
                worker_cpus=args.worker_cpus,
            )
            samplers[n].broadcast(policy)
            samplers[n].run([Request(k, EPSILON) for k in range(n)])  # warm up every worker
        in_process_round(local, policy, 2.0, 0)
        rounds: dict[str, list[float]] = {"in_process": [], **{str(n): [] for n in samplers}}
        for r in range(args.repeats):
            seed = 100_000 * (r + 1)
            rounds["in_process"].append(in_process_round(local, policy, args.seconds, seed))
            for n, sampler in samplers.items():
                rounds[str(n)].append(ray_round(sampler, args.seconds, seed))
    finally:
        for sampler in samplers.values():
            sampler.close()
        local.close()
        ray.shutdown()

    base = rounds["in_process"]
    rows: list[dict[str, Any]] = [
        {
            "sampling": "in-process loop (no Ray)",
            "workers": 1,
            "steps_per_s": statistics.median(base),
            "ratio": 1.0,
            "per_worker": statistics.median(base),
        }
    ]
    for n in samplers:
        rates = rounds[str(n)]
        rows.append(
            {
                "sampling": f"Ray, env={args.env}",
                "workers": n,
                "steps_per_s": statistics.median(rates),
                "ratio": statistics.median([a / b for a, b in zip(rates, base, strict=True)]),
                "per_worker": statistics.median(rates) / n,
            }
        )
    print(table(rows, ["sampling", "workers", "steps_per_s", "ratio", "per_worker"]))
    report = {
        "seconds_per_round": args.seconds,
        "repeats": args.repeats,
        "env": args.env,
        "worker_cpus": args.worker_cpus,
        "epsilon": EPSILON,
        "rows": rows,
        "rounds": rounds,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('sampling', report)}")


if __name__ == "__main__":
    main()
