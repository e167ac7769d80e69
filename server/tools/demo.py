"""``neuronsmae-demo``: one bot-against-bot episode, printing the referee's summary.

A smoke test a new user can run right after installing: it builds an arena, plays the hard
bot (blue) against the easy bot (red) and prints what the referee recorded.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence

from neuronsmae.protocol.defaults import DEFAULT_SEED
from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg
from neuronsmae.protocol.messages import MAX_SEED
from neuronsmae.server.arena import Arena


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point."""
    parser = argparse.ArgumentParser(prog="neuronsmae-demo", description=__doc__.split("\n")[0])
    parser.add_argument("--blue", default="hard", choices=LEVEL_ARGS, help="blue bot level")
    parser.add_argument("--red", default="easy", choices=LEVEL_ARGS, help="red bot level")
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED)
    args = parser.parse_args(argv)
    if not 0 <= args.seed <= MAX_SEED:
        parser.error(f"--seed must be in 0..{MAX_SEED}, got {args.seed}")
    blue_level = level_from_arg(args.blue)
    with Arena(seed=args.seed, mode="bots", blue_level=blue_level) as arena:
        arena.reset({"level": level_from_arg(args.red)})
        start, decisions, done, info = time.perf_counter(), 0, False, {}
        while not done:
            _, _, done, info = arena.step([])
            decisions += 1
        wall = time.perf_counter() - start
    print(
        f"blue ({args.blue}) vs red ({args.red}), seed {args.seed}: winner {info['winner']} "
        f"after {info['t'] * 0.02:.1f} s simulated, {wall:.2f} s wall ({decisions} decisions)"
    )
    names = [f"blue_{i}" for i in range(2)] + [f"red_{i}" for i in range(2)]
    print(f"{'robot':8s} {'HP':>6s} {'bullets':>8s} {'dealt':>7s} {'taken':>7s} {'kills':>6s}")
    for k, name in enumerate(names):
        print(
            f"{name:8s} {info['hp'][k]:6.0f} {info['bullets'][k]:8d} "
            f"{info['damage_dealt'][k]:7.1f} {info['damage_taken'][k]:7.1f} "
            f"{info['kills'][k]:6d}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
