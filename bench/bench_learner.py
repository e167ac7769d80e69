"""The learner alone: updates/s and sampled transitions/s of each learner, on CPU and CUDA.

    python -m bench.bench_learner [--learners defaults released] [--algs vdn qmix iql]
                                  [--batches 32 128 512] [--transitions 2000 20000]
                                  [--threads 1 2] [--device cpu cuda] [--updates 20]
                                  [--repeats 3] [--reference] [--out FILE]

Synthetic replay of the 2 v 2 abstract task's sizes (observation 37, 8 actions, episodes of
28–50 decisions, 39 on average as the main job's; its ``get_env_info()`` is written below,
so no simulator is needed).
``defaults`` is this project's learner as ``neuronsmae-train`` resolves it for that task (a
GRU on derived features with the points head, TD(λ) targets, the task's symmetries), at
``--batches`` episodes per update; ``released`` is ``--preset paper``'s (the MLP on single
transitions), at ``--transitions`` transitions per update.

Each cell is timed ``--repeats`` times for ``--updates`` updates after three warm-up ones;
the table gives the median ms per update, updates/s and transitions drawn per second
(padding not counted). A batch is drawn, augmented and sent to the device as the trainer does
it (``--prefetch``, ``learner.prefetch``'s values: by default in a background thread while
the previous update runs when the learner leaves a core free, else inline). ``--reference``
also times the step as it was before the faster learner (the λ-returns by a Python loop
over time steps, the points head's first form, each batch drawn inline) in the same
repeats, interleaved, and reports the ratio. CPU cells run with ``torch.set_num_threads(t)``;
CUDA cells only where torch sees a device.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from typing import Any

import numpy as np
import torch

from bench.common import Distinct, add_out, at_least, machine, out_problem, table, write_json
from bench.common import write_out as write_to
from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.trainers.core import agent as agent_module
from neuronsmae.trainers.core import learner as learner_module
from neuronsmae.trainers.core.buffer import (
    PREFETCH,
    REPLAYS,
    Batch,
    Episode,
    prefetch_pays,
    prefetched,
)
from neuronsmae.trainers.core.learner import EnvSpec, QLearner, agent_spec
from neuronsmae.trainers.core.symmetry import augment, parse_generators, task_group
from neuronsmae.trainers.run.config import make_config, preset
from neuronsmae.trainers.run.config_groups import resolve_learner
from neuronsmae.trainers.run.learning import make_learner

TASK = {
    "n_actions": 8, "n_agents": 2, "state_shape": 21, "obs_shape": 37, "episode_limit": 50,
    "action_space": "abstract", "agents": ["blue_0", "blue_1"], "n_enemies": 2,
    "decision_steps": 20, "mode": "cooperative", "team_size": 2, "k": 4,
    "candidate_obs": True, "vector_obs": True, "lidar_beams": 0,
}  # fmt: skip
"""The default 2 v 2 abstract task's ``get_env_info()``."""
LENGTHS = (28, 50)
"""Episode lengths drawn uniformly in this range (decisions): a mean of 39, the main job's
(a team can be wiped out before the 50th decision, so batches carry padding)."""
STORED = {"episodes": 600, "transitions": 40_000}
"""Replay filled before timing: episodes, or transitions (800 episodes of 50)."""


class Cell:
    """One learner at one batch size on one device, with its replay and batch maker."""

    def __init__(
        self, learner: str, alg: str, batch: int, device: torch.device, seed: int,
        prefetch: str = "auto",
    ) -> None:  # fmt: skip
        info = EnvInfo.from_dict(TASK)
        cfg = make_config(preset("paper") if learner == "released" else {}, {"alg": alg})
        lc = resolve_learner(cfg.learner, info, "full", "random")
        self.env = EnvSpec.of(info, lc.features)
        spec = agent_spec(
            self.env, lc.agent_hidden, lc.last_action_input, lc.agent_id_input, lc.features,
            lc.head, info, lc.agent_net, lc.action_masks == "env",
        )  # fmt: skip
        torch.manual_seed(seed)
        self.learner: QLearner = make_learner(self.env, spec, alg, cfg.learner, device)
        self.background = prefetch_pays(prefetch, device)
        """Whether the faster step draws its next batch in a background thread (as a run
        with ``learner.prefetch`` = ``prefetch`` would, at the threads set when built)."""
        self.group = task_group(parse_generators(lc.augment), lc.features, info)
        self.batch, self.rng = batch, np.random.default_rng(seed)
        e = self.env
        self.replay = REPLAYS[lc.replay](STORED[lc.replay], e.n_agents, e.obs_dim, e.state_dim,
                                         e.n_actions, e.episode_limit)  # fmt: skip
        while len(self.replay) < STORED[lc.replay]:
            self.replay.add(self._episode())

    def _episode(self) -> Episode:
        e, rng = self.env, self.rng
        steps = int(rng.integers(LENGTHS[0], LENGTHS[1] + 1))
        return Episode(
            obs=rng.uniform(-1, 1, (steps + 1, e.n_agents, e.obs_dim)).astype(np.float32),
            state=rng.uniform(-1, 1, (steps + 1, e.state_dim)).astype(np.float32),
            avail=np.ones((steps + 1, e.n_agents, e.n_actions), np.int8),
            alive=np.ones((steps + 1, e.n_agents), bool),
            actions=rng.integers(0, e.n_actions, (steps, e.n_agents)),
            rewards=rng.standard_normal(steps).astype(np.float32),
            terminated=True,
        )

    def make(self) -> Batch:
        """A batch drawn and augmented as the trainer draws it, on the learner's device."""
        batch = augment(self.replay.sample(self.batch, self.rng), self.group, self.rng)
        return batch.to(self.learner.device)

    def timed(self, updates: int, reference: bool) -> tuple[float, int]:
        """Seconds for ``updates`` updates, and the transitions they drew. ``reference``: the
        step before the faster learner (λ-return loop, the points head's first form, batches
        drawn inline)."""
        learner = self.learner
        fast, fast_head = learner_module.lambda_returns, agent_module._QNetwork._score_points
        if reference:
            learner_module.lambda_returns = learner_module.lambda_returns_loop
            agent_module._QNetwork._score_points = agent_module.score_points_sum  # type: ignore[method-assign]
        try:
            before = learner.samples
            self._sync()
            start = time.perf_counter()
            if reference:
                for _ in range(updates):
                    learner.train(self.make())
            else:
                for batch in prefetched(self.make, updates, self.background):
                    learner.train(batch)
            self._sync()
            return time.perf_counter() - start, learner.samples - before
        finally:
            learner_module.lambda_returns = fast
            agent_module._QNetwork._score_points = fast_head  # type: ignore[method-assign]

    def _sync(self) -> None:
        if self.learner.device.type == "cuda":
            torch.cuda.synchronize(self.learner.device)


def measure(cell: Cell, args: argparse.Namespace) -> dict[str, Any]:
    """Median figures of ``cell`` (and of its reference step, interleaved, if asked)."""
    cell.timed(3, reference=False)
    runs: dict[str, list[tuple[float, int]]] = {"new": [], "reference": []}
    for _ in range(args.repeats):
        runs["new"].append(cell.timed(args.updates, reference=False))
        if args.reference:
            runs["reference"].append(cell.timed(args.updates, reference=True))
    out: dict[str, Any] = {}
    for name, rows in runs.items():
        if not rows:
            continue
        ms = statistics.median(1000 * s / args.updates for s, _ in rows)
        per_s = statistics.median(n / s for s, n in rows)
        out[name] = {"ms_per_update": ms, "updates_per_s": 1000 / ms, "transitions_per_s": per_s}
    if args.reference:
        out["speedup"] = out["reference"]["ms_per_update"] / out["new"]["ms_per_update"]
    return out


def cells(args: argparse.Namespace) -> list[tuple[str, str, int, str, int]]:
    """(learner, alg, batch, device, threads) of every cell asked for."""
    out = []
    for device in args.device:
        threads = args.threads if device == "cpu" else [0]
        for learner in args.learners:
            sizes = args.batches if learner == "defaults" else args.transitions
            for alg in args.algs:
                out += [(learner, alg, b, device, t) for b in sizes for t in threads]
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--learners", nargs="+", action=Distinct, choices=("defaults", "released"),
                   default=["defaults", "released"])  # fmt: skip
    p.add_argument("--algs", nargs="+", action=Distinct, choices=("vdn", "qmix", "iql"),
                   default=["vdn", "qmix", "iql"])  # fmt: skip
    p.add_argument("--batches", nargs="+", type=at_least(1), default=[32, 128, 512],
                   help="episodes per batch of the defaults' learner")  # fmt: skip
    p.add_argument("--transitions", nargs="+", type=at_least(1), default=[2000, 20_000],
                   help="transitions per batch of the released learner")  # fmt: skip
    p.add_argument("--threads", nargs="+", type=at_least(1), default=[1, 2])
    p.add_argument("--device", nargs="+", action=Distinct, choices=("cpu", "cuda"),
                   default=["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"])  # fmt: skip
    p.add_argument("--updates", type=at_least(1), default=20)
    p.add_argument("--repeats", type=at_least(1), default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--prefetch", choices=PREFETCH, default="auto",
                   help="the faster step's batches in a background thread: learner.prefetch's "
                   "values (auto: when the learner leaves a core free)")  # fmt: skip
    p.add_argument("--reference", action="store_true",
                   help="time the step before the faster learner beside it (ratio)")  # fmt: skip
    add_out(p, "learner")
    args = p.parse_args(argv)
    if "cuda" in args.device and not torch.cuda.is_available():
        p.error("--device cuda: torch sees no CUDA device here")
    if (problem := out_problem(args.out, args.force)) is not None:
        p.error(problem)
    rows = []
    for learner, alg, batch, device, threads in cells(args):
        if device == "cpu":
            torch.set_num_threads(threads)
        cell = Cell(learner, alg, batch, torch.device(device), args.seed, args.prefetch)
        figures = measure(cell, args)
        row = {"learner": learner, "alg": alg, "batch": batch, "device": device,
               "threads": threads or None, "prefetch": cell.background, **figures}  # fmt: skip
        rows.append(row)
        print(_line(row), flush=True)
    print(table([_flat(r) for r in rows], list(_flat(rows[0]))))
    payload = {"what": "learner-only updates on synthetic 2 v 2 abstract batches",
               "command": " ".join(["python -m bench.bench_learner", *(argv or sys.argv[1:])]),
               "machine": machine(), "torch": torch.__version__,
               "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
               "updates": args.updates, "repeats": args.repeats, "rows": rows}  # fmt: skip
    print(f"wrote {write_to(args.out, payload) if args.out else write_json('learner', payload)}")
    return 0


def _flat(row: dict[str, Any]) -> dict[str, Any]:
    new = row["new"]
    flat = {k: row[k] for k in ("learner", "alg", "batch", "device", "threads")}
    flat["prefetch"] = "background" if row.get("prefetch", True) else "inline"
    flat |= {"ms/update": f"{new['ms_per_update']:.1f}", "updates/s": f"{new['updates_per_s']:.1f}",
             "transitions/s": f"{new['transitions_per_s']:,.0f}"}  # fmt: skip
    if "speedup" in row:
        flat |= {"reference ms": f"{row['reference']['ms_per_update']:.1f}",
                 "speedup": f"{row['speedup']:.2f}"}  # fmt: skip
    return flat


def _line(row: dict[str, Any]) -> str:
    return " ".join(f"{k}={v}" for k, v in _flat(row).items())


if __name__ == "__main__":
    sys.exit(main())
