"""Training speed against worker count: episodes and updates per minute on a Ray cluster.

    python -m bench.bench_training_scaling [--workers 1 2 4 8] [--learners defaults released]
                                           [--minutes 2] [--env inprocess] [--decoupled]
                                           [--out FILE]

For each learner and worker count, a fresh ``ray.cluster_utils.Cluster`` (a head node for
the learner and one node holding the workers, each worker requiring one unit of its
``sampler`` resource, as on a real cluster) runs a training for ``--minutes`` of wall time
and reports the training episodes, environment steps and gradient updates per minute, and
the share of the wall time the learner spent in updates. ``defaults`` is this project's
learner (asynchronous; ``--decoupled`` adds its rows with ``learner.replay_ratio=2``, the
learner in its own thread); ``released`` is ``--preset paper`` (iterations of 20 episodes,
then their updates). On a machine with fewer cores than workers the workers share them:
the rows then show the shape of the curve under oversubscription, not a cluster's speed.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import ray
from ray.cluster_utils import Cluster

from bench.common import Distinct, add_out, at_least, machine, out_problem, table, write_json
from bench.common import write_out as write_to
from neuronsmae.trainers.run.config import make_config, preset
from neuronsmae.trainers.run.train import Trainer

NODE = {"node_ip_address": "127.0.0.1", "object_store_memory": 200 * 1024 * 1024}


def config(learner: str, workers: int, args: argparse.Namespace, out: Path) -> Any:
    """The run of one row: ``learner``'s settings with ``workers`` workers for the budget."""
    base = preset("paper") if learner == "released" else {}
    extra = {"learner.replay_ratio": 2.0} if learner == "decoupled" else {}
    return make_config(base, extra, {
        "alg": "vdn", "level": "easy", "workers": workers, "env": args.env,
        "max_minutes": args.minutes, "episodes": 10**7, "eval.eval_every": 0,
        "eval.final_eval_episodes": 2, "eval.extra_test_contexts": "", "eval.keep_best": False,
        "cluster.worker_resources": "sampler=1", "cluster.worker_cpus": 1.0,
        "progress": False, "out": str(out), "torch_threads": 1,
    })  # fmt: skip


def loopback_clusters() -> None:
    """Keep every address of the local clusters on 127.0.0.1 and out of
    ``/tmp/ray/ray_current_cluster``: Ray rewrites a loopback address to the machine's
    outward IP unless "clusters" are off (a switch read once at import, set here for this
    process and the ones the clusters start), and a plain ``ray.init()`` elsewhere would
    join a cluster it found recorded there."""
    from ray._private import ray_constants

    os.environ[ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR] = "0"
    ray_constants.ENABLE_RAY_CLUSTER = False
    ray._private.utils.write_ray_address = lambda *a, **k: None
    ray._common.utils.reset_ray_address = lambda *a, **k: None


def one_row(learner: str, workers: int, args: argparse.Namespace) -> dict[str, Any]:
    """Train once on a fresh two-node cluster; the rates of its training phase."""
    cluster = Cluster(
        initialize_head=True,
        head_node_args={**NODE, "num_cpus": 1, "include_dashboard": False},
    )
    try:
        cluster.add_node(**NODE, num_cpus=workers, resources={"sampler": workers})
        ray.init(
            address=cluster.address,
            _node_ip_address="127.0.0.1",
            log_to_driver=False,
            logging_level=logging.WARNING,
        )
        with tempfile.TemporaryDirectory(prefix="scaling-") as folder:
            start = time.perf_counter()
            result = Trainer(config(learner, workers, args, Path(folder) / "run")).run()
            total = time.perf_counter() - start
        c = result["counters"]
        minutes = c["wall_seconds"] / 60
        return {
            "learner": learner, "workers": workers, "training_minutes": round(minutes, 2),
            "episodes_per_min": c["episodes"] / minutes,
            "env_steps_per_min": c["env_steps"] / minutes,
            "updates_per_min": c["updates"] / minutes,
            "learner_share": c["learn_seconds"] / c["wall_seconds"],
            "episodes": c["episodes"], "updates": c["updates"], "seconds_in_all": round(total, 1),
        }  # fmt: skip
    finally:
        ray.shutdown()
        cluster.shutdown()


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--workers", nargs="+", action=Distinct, type=at_least(1), default=[1, 2, 4, 8])
    p.add_argument("--learners", nargs="+", action=Distinct, choices=("defaults", "released"),
                   default=["defaults", "released"])  # fmt: skip
    p.add_argument(
        "--decoupled", action="store_true",
        help="also the defaults with the learner in its own thread (replay_ratio 2)",
    )  # fmt: skip
    p.add_argument("--minutes", type=float, default=2.0, help="training budget per row (2)")
    p.add_argument("--env", choices=("inprocess", "remote"), default="inprocess")
    add_out(p, "training_scaling")
    args = p.parse_args(argv)
    if not args.minutes > 0:
        p.error(f"--minutes must be > 0, got {args.minutes}")
    if (problem := out_problem(args.out, args.force)) is not None:
        p.error(problem)
    loopback_clusters()
    learners = list(args.learners) + (["decoupled"] if args.decoupled else [])
    rows = []
    for learner in learners:
        for workers in args.workers:
            row = one_row(learner, workers, args)
            rows.append(row)
            print(" ".join(f"{k}={v:.3g}" if isinstance(v, float) else f"{k}={v}"
                           for k, v in row.items()), flush=True)  # fmt: skip
    shown = [{k: (f"{v:,.1f}" if isinstance(v, float) else v) for k, v in r.items()} for r in rows]
    print(table(shown, list(shown[0])))
    payload = {
        "what": "training speed against worker count on a ray.cluster_utils.Cluster",
        "command": " ".join(["python -m bench.bench_training_scaling", *(argv or sys.argv[1:])]),
        "machine": machine(), "cores": os.cpu_count(), "minutes": args.minutes, "env": args.env,
        "rows": rows,
    }  # fmt: skip
    written = write_to(args.out, payload) if args.out else write_json("training_scaling", payload)
    print(f"wrote {written}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
