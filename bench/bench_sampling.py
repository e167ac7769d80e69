"""Sampling throughput: the trainers' rollout workers against the bare arena, same run.

    python -m bench.bench_sampling [--envs 1 8] [--workers 1 2] [--groups 1] [--servers 1 2]
                                   [--seconds 10] [--repeats 3]

What a learner sees: env steps (decisions) per second of *finished episodes*, policy
included: the ε-greedy GRU agent of the default architecture (untrained: acting costs the
same whatever the weights) at ε = 0.2 against the easy bot, the feature code and the
episode packing that training uses. Rows:

* **bare arena**: one in-process ``Arena`` stepped with random available actions, no
  policy, no packing: the simulator's own rate on one core, the reference of every ratio;
* **worker, no Ray**: one ``RolloutWorker`` with ``envs`` in-process arenas called directly
  in this process (one batched forward per decision for all its arenas);
* **Ray**: the trainers' ``Sampler`` with ``workers`` Ray actors of ``envs`` arenas each,
  ``inprocess`` (a ``VecArena`` in the worker) or ``remote`` (a ``VecRM`` of the worker's
  own vector server(s), unpaced), two chunks in flight per worker, ``per_worker`` = total /
  n. A served worker's arenas are held by ``servers`` private servers stepped side by side
  (``cluster.servers_per_worker``) and played in ``groups`` stepped in turn (the worker
  chooses one group's actions while the other's step; ``cluster.groups``): each combination
  of ``--servers`` and ``--groups`` is a row of its own.

**Target: a worker delivers ≥ 0.75 of the bare rate with envs = 8** (the ``ratio`` column:
per-worker rate / bare rate, medians of the paired rounds). Rounds alternate between every
row, so load from other processes hits them alike. Learning is not included (it would
compete for the same cores). Prints a Markdown table and writes bench/out/sampling.json.
"""

from __future__ import annotations

import argparse
import logging
import math
import statistics
import time
from typing import Any

import numpy as np
import ray

from bench.common import Distinct, arena_count, at_least, machine, positive, table, write_json
from neuronsmae.protocol import EnvInfo
from neuronsmae.server import Arena
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.learner import EnvSpec, agent_spec
from neuronsmae.trainers.play.rollout import Request, RolloutWorker
from neuronsmae.trainers.run.sampler import Sampler

CONTEXTS = {"level": "easy"}
EPSILON = 0.2
TARGET = 0.75
TARGET_ENVS = 8
ENV_KINDS = ("inprocess", "remote")


def make_policy(info: dict[str, Any]) -> Policy:
    """An untrained agent of the default architecture, as the trainer would broadcast."""
    layout = EnvInfo.from_dict(info)
    env = EnvSpec.of(layout, "relative")
    spec = agent_spec(env, 128, True, True, "relative", "points", layout)
    weights = {k: v.detach().numpy().copy() for k, v in spec.build().state_dict().items()}
    return Policy(spec, weights)


def bare_round(arena: Arena, seconds: float, rng: np.random.Generator) -> float:
    """Decisions per second of an arena driven with random available actions."""
    steps, start = 0, time.perf_counter()
    arena.reset(CONTEXTS)
    while time.perf_counter() - start < seconds:
        actions = [int(rng.choice(np.flatnonzero(m))) for m in arena.get_avail_actions()]
        if arena.step(actions)[2]:
            arena.reset(CONTEXTS)
        steps += 1
    return steps / (time.perf_counter() - start)


def worker_round(worker: RolloutWorker, policy: Policy, seconds: float, seed: int) -> float:
    """Env steps per second of whole episodes a worker plays in this process."""
    steps, start, k = 0, time.perf_counter(), seed
    while time.perf_counter() - start < seconds:
        requests = [Request(k + j, EPSILON, CONTEXTS) for j in range(worker.envs)]
        steps += sum(e.length for e in worker.run(policy, 0, requests))
        k += worker.envs
    return steps / (time.perf_counter() - start)


def ray_round(sampler: Sampler, seconds: float, seed: int) -> float:
    """Env steps per second of the episodes that landed within ``seconds``.

    The pipeline is filled first and kept full; only episodes that finish inside the window
    count, and the window ends at the last landing, so a half-played episode is never
    credited.
    """
    k = seed

    def fill() -> None:
        nonlocal k
        while sampler.idle_slots() > 0:
            sampler.submit([Request(k + j, EPSILON, CONTEXTS) for j in range(sampler.envs)])
            k += sampler.envs

    fill()
    steps, start, last = 0, time.perf_counter(), time.perf_counter()
    while time.perf_counter() - start < seconds:
        for episode in sampler.wait(timeout=seconds):
            steps += episode.length
            last = time.perf_counter()
        fill()
    while sampler.in_flight:  # let in-flight episodes land before the next round
        sampler.wait(timeout=120)
    return steps / max(last - start, 1e-9)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", type=arena_count, nargs="+", action=Distinct, default=[1, 8])
    parser.add_argument("--workers", type=at_least(1), nargs="+", action=Distinct, default=[1, 2])
    parser.add_argument(
        "--env", nargs="+", action=Distinct, choices=ENV_KINDS, default=list(ENV_KINDS)
    )
    parser.add_argument("--seconds", type=positive, default=10.0)
    parser.add_argument("--repeats", type=at_least(1), default=3)
    parser.add_argument("--worker-cpus", type=positive, default=0.5)
    parser.add_argument(
        "--groups",
        type=at_least(1),
        nargs="+",
        action=Distinct,
        default=[1],
        help="served rows (1)",
    )
    parser.add_argument(
        "--servers",
        type=at_least(1),
        nargs="+",
        action=Distinct,
        default=[1, 2],
        help="served rows",
    )
    return parser


def _args(argv: list[str] | None = None) -> argparse.Namespace:
    """The options, refusing a served row whose worker would have more servers than arenas."""
    parser = _parser()
    args = parser.parse_args(argv)
    served = [e for e in args.envs if e > 1] if "remote" in args.env else []
    if served and max(args.servers) > min(served):
        parser.error(
            f"--servers must not exceed --envs in a served row (a server holds at least one "
            f"arena): got --servers {max(args.servers)} with --envs {min(served)}"
        )
    if served and max(args.groups) > min(served):
        parser.error(
            f"--groups must not exceed --envs in a served row (a group holds at least one "
            f"arena; the row would be labelled with groups it does not have): got --groups "
            f"{max(args.groups)} with --envs {min(served)}"
        )
    return args


Combo = tuple[int, int, str, int, int]
"""One Ray sampler measured: workers, envs per worker, env kind, groups, servers per worker."""


def _combos(args: argparse.Namespace) -> list[Combo]:
    return [
        (n, e, kind, g, s)
        for n in args.workers
        for e in args.envs
        for kind in args.env
        for s in (args.servers if kind == "remote" and e > 1 else [1])
        for g in (args.groups if kind == "remote" and e > 1 else [1])
    ]


def _measure(args: argparse.Namespace, combos: list[Combo]) -> dict[str, list[float]]:
    """Interleaved rounds of the bare arena, a local worker per envs count and every Ray
    sampler; env steps per second (per worker for the samplers), one entry per round."""
    # Every sampler's actors live at once (rounds interleave), so Ray must be told there
    # are enough CPUs for all of them; they still share the machine's real cores.
    cpus = math.ceil(sum(n for n, *_ in combos) * args.worker_cpus) + 1
    ray.init(
        num_cpus=cpus, include_dashboard=False, logging_level=logging.WARNING, log_to_driver=False
    )
    arena = Arena(seed=1)
    local = {e: RolloutWorker(0, "inprocess", 1, None, envs=e) for e in args.envs}
    policy = make_policy(local[args.envs[0]].env_info())
    samplers: dict[Combo, Sampler] = {}
    rounds: dict[str, list[float]] = {"bare": []}
    try:
        for n, e, kind, g, s in combos:
            sampler = Sampler(
                n,
                env_kind=kind,
                base_seed=1000,
                envs_per_worker=e,
                groups=g,
                servers_per_worker=s,
                worker_cpus=args.worker_cpus,
            )
            sampler.broadcast(policy)
            sampler.run([Request(k, EPSILON, CONTEXTS) for k in range(n * e)])  # warm up
            samplers[(n, e, kind, g, s)] = sampler
        for worker in local.values():
            worker_round(worker, policy, 2.0, 0)
        bare_round(arena, 2.0, np.random.default_rng(0))
        for r in range(args.repeats):
            seed = 100_000 * (r + 1)
            rounds["bare"].append(bare_round(arena, args.seconds, np.random.default_rng(r)))
            for e, worker in local.items():
                key = f"worker {e}"
                rounds.setdefault(key, []).append(worker_round(worker, policy, args.seconds, seed))
            for (n, e, kind, g, s), sampler in samplers.items():
                key = f"ray {n} {e} {kind} {g} {s}"
                rounds.setdefault(key, []).append(ray_round(sampler, args.seconds, seed) / n)
    finally:
        for sampler in samplers.values():
            sampler.close()
        for worker in local.values():
            worker.close()
        arena.close()
        ray.shutdown()
    return rounds


def _row(rounds: dict[str, list[float]], label: str, key: str, combo: Combo) -> dict[str, Any]:
    """One table row: the median rate over rounds and the median of its per-round ratio to
    the bare arena's rate in the same round."""
    workers, envs, env, groups, servers = combo
    rates = rounds[key]
    return {
        "sampling": label,
        "workers": workers,
        "envs": envs,
        "env": env,
        "groups": groups,
        "servers": servers,
        "steps_per_s_per_worker": statistics.median(rates),
        "ratio": statistics.median([a / b for a, b in zip(rates, rounds["bare"], strict=True)]),
    }


def main() -> None:
    args = _args()
    combos = _combos(args)
    rounds = _measure(args, combos)
    rows = [_row(rounds, "bare arena, random actions", "bare", (1, 1, "inprocess", 1, 1))]
    rows += [
        _row(rounds, "worker, no Ray", f"worker {e}", (1, e, "inprocess", 1, 1))
        for e in dict.fromkeys(args.envs)
    ]
    rows += [_row(rounds, "Ray sampler", "ray {} {} {} {} {}".format(*c), c) for c in combos]
    columns = ["sampling", "workers", "envs", "env", "servers", "groups"]
    columns += ["steps_per_s_per_worker", "ratio"]
    print(table(rows, columns))
    print(f"target: per-worker rate ≥ {TARGET} of the bare arena's with envs = {TARGET_ENVS}")
    report = {
        "seconds_per_round": args.seconds,
        "repeats": args.repeats,
        "worker_cpus": args.worker_cpus,
        "epsilon": EPSILON,
        "target": {"ratio": TARGET, "envs": TARGET_ENVS},
        "rows": rows,
        "rounds": rounds,
        "machine": machine(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    print(f"wrote {write_json('sampling', report)}")


if __name__ == "__main__":
    main()
