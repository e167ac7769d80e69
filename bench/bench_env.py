"""In-process speed of the arena against bare PyBullet stepping of the same world.

    python -m bench.bench_env [--seconds 3] [--repeats 5]

Measures decisions per second for 2 v 2 with the full referee in each action space (and
with LiDAR), and, interleaved in the same run, two baselines on the same PyBullet world with
the same four robot bodies: ``bare step`` (only ``stepSimulation``, 20 per decision, robots
moving and colliding) and ``bare drive`` (the least a planar-robot loop must do: set each
robot's velocity, step, read each pose); and the frames per second of ``Arena.render`` on
the costliest frame (abstract 2 v 2 with LiDAR beams, mid-episode). Prints a Markdown table
and writes bench/out/env.json. Medians of ``--repeats`` runs; every configuration is
measured in turn within each repeat so that machine noise hits them alike.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
import pybullet as pb

from bench.common import at_least, finite, machine, rate, table, write_json
from neuronsmae.server import Arena
from neuronsmae.server.config import ArenaConfig
from neuronsmae.server.sim.field import PHYSICS_DT
from neuronsmae.server.sim.world import World

CONFIGS = {
    "continuous": {"action_space": "continuous"},
    "discrete (0.4 s)": {"action_space": "discrete", "decision_steps": 20},
    "abstract": {"action_space": "abstract"},
    "abstract + LiDAR": {"action_space": "abstract", "lidar": True},
    "abstract, partial obs": {"action_space": "abstract", "observability": "partial"},
}


def random_available(arena: Arena, rng: np.random.Generator) -> list[int]:
    """A random available action for every agent (abstract or discrete)."""
    return [int(rng.choice(np.flatnonzero(m))) for m in arena.get_avail_actions()]


def arena_runner(options: dict, seed: int = 0):
    """A closure playing one decision with random available actions; returns 1."""
    arena = Arena(seed=seed, **options)
    arena.reset({"level": "easy"})
    rng = np.random.default_rng(seed)
    continuous = options["action_space"] == "continuous"
    n = arena.get_env_info()["n_agents"]

    def one() -> int:
        if continuous:
            acts = [
                np.array([*rng.uniform(-1.5, 1.5, 2), rng.uniform(-1.5, 1.5), rng.integers(2)])
                for _ in range(n)
            ]
        else:
            acts = random_available(arena, rng)
        _, _, done, _ = arena.step(acts)
        if done:
            arena.reset({"level": "easy"})
        return 1

    return one


BARE_STEPS = 20
"""Physics steps per 'decision' of the baselines (an abstract decision's 0.4 s)."""


def seconds_per_decision(name: str) -> float:
    """Simulated seconds one decision of configuration ``name`` covers."""
    steps = ArenaConfig.from_options(CONFIGS[name]).period if name in CONFIGS else BARE_STEPS
    return steps * PHYSICS_DT


def bare_runners(seed: int = 0):
    """Baselines on the same world: ``BARE_STEPS`` physics steps per 'decision'."""
    world = World(4)
    rng = np.random.default_rng(seed)
    poses = np.array([(1.0, 1.0, 0.0), (1.0, 3.5, 0.0), (7.0, 1.0, math.pi), (7.0, 3.5, 0.0)])
    world.build(poses)
    cid, bodies = world.client, world.bodies

    def kick() -> None:
        for b in bodies:
            v = rng.uniform(-1.5, 1.5, 2)
            pb.resetBaseVelocity(
                b, (v[0], v[1], 0.0), (0.0, 0.0, rng.uniform(-1, 1)), physicsClientId=cid
            )

    def step_only() -> int:
        kick()
        for _ in range(BARE_STEPS):
            pb.stepSimulation(physicsClientId=cid)
        return 1

    def drive() -> int:
        vel = [(*rng.uniform(-1.5, 1.5, 2), 0.0) for _ in bodies]
        for _ in range(BARE_STEPS):
            for b, v in zip(bodies, vel, strict=True):
                pb.resetBaseVelocity(b, v, (0.0, 0.0, 0.5), cid)
            pb.stepSimulation(physicsClientId=cid)
            for b in bodies:
                pb.getBasePositionAndOrientation(b, cid)
        return 1

    return {"bare step": step_only, "bare drive": drive}


RENDER = "render (frame with LiDAR)"
"""The rendering runner's name: frames per second, not decisions."""


def render_runner(seed: int = 0):
    """A closure drawing one top-down frame of an abstract 2 v 2 with LiDAR beams (the
    costliest frame) in mid-episode; returns 1."""
    arena = Arena(seed=seed, action_space="abstract", lidar=True)
    arena.reset({"level": "easy"})
    rng = np.random.default_rng(seed)
    for _ in range(10):
        if arena.step(random_available(arena, rng))[2]:
            arena.reset({"level": "easy"})
    arena.render()  # font and background caches

    def one() -> int:
        arena.render()
        return 1

    return one


MIN_SECONDS = 0.05
"""Shortest measuring time: long enough for every configuration to play a decision (a
nanosecond played none and divided by zero)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--seconds", type=finite(MIN_SECONDS), default=3.0,
        help=f"measuring time per configuration and repeat, ≥ {MIN_SECONDS} s",
    )  # fmt: skip
    parser.add_argument("--repeats", type=at_least(1), default=5)
    args = parser.parse_args()
    runners = bare_runners() | {name: arena_runner(opts) for name, opts in CONFIGS.items()}
    runners[RENDER] = render_runner()
    samples: dict[str, list[float]] = {name: [] for name in runners}
    for _ in range(args.repeats):
        for name, fn in runners.items():
            samples[name].append(rate(fn, args.seconds, 1)["median"])
    med = {name: float(np.median(v)) for name, v in samples.items()}
    rows = []
    for name, value in med.items():
        if name == RENDER:
            continue
        rows.append(
            {
                "configuration": name,
                "decisions/s (median)": value,
                "× real time": value * seconds_per_decision(name),
                "% of bare step": 100 * value / med["bare step"],
                "% of bare drive": 100 * value / med["bare drive"],
                "min": float(min(samples[name])),
                "max": float(max(samples[name])),
            }
        )
    print(
        table(
            rows,
            [
                "configuration",
                "decisions/s (median)",
                "× real time",
                "% of bare step",
                "% of bare drive",
                "min",
                "max",
            ],
        )
    )
    frames = med[RENDER]
    render = {
        "frames_per_s": frames,
        "ms_per_frame": 1000 / frames,
        "episode_of_51_frames_s": 51 / frames,
        "min": float(min(samples[RENDER])),
        "max": float(max(samples[RENDER])),
    }
    print(
        f"{RENDER}: {frames:,.0f} frames/s (median), {render['ms_per_frame']:.1f} ms a frame, "
        f"an episode's 51 frames in {render['episode_of_51_frames_s']:.2f} s"
    )
    path = write_json(
        "env",
        {
            "rows": rows,
            "render": render,
            "samples": samples,
            "machine": machine(),
            "seconds": args.seconds,
            "repeats": args.repeats,
        },
    )
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
