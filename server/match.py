"""``neuronsmae-match``: play bots (or trained policies) against each other and score them.

    neuronsmae-match --blue hard --red easy --episodes 200 --seed 0 [--json]

``--blue`` and ``--red`` take a bot level (easy, middle, hard, random). ``--blue`` may also
be a path to a trained checkpoint: the policy is loaded through the ``neuronsmae.policies``
entry-point group (the trainers register theirs), so the server package never imports the
trainers. Episode ``i`` uses seed ``seed + i``, so two runs with the same arguments give the
same numbers.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from collections.abc import Sequence
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, Protocol

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.server.arena import Arena
from neuronsmae.server.config import LEVEL_NAMES

Z95 = 1.959963984540054


class Policy(Protocol):
    """What a loaded checkpoint offers the match: greedy actions for the blue agents."""

    options: dict[str, Any]
    """Arena options the policy was trained with."""

    def reset(self) -> None: ...

    def act(self, obs: list[Any], avail: list[Any], state: Any) -> list[int]: ...


def wilson(k: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval for a proportion k/n (well behaved near 0 and 1)."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def load_policy(path: str) -> Policy:
    """Load a checkpoint through the first ``neuronsmae.policies`` entry point that takes it."""
    loaders = list(entry_points(group="neuronsmae.policies"))
    if not loaders:
        raise InvalidOptionError(
            f"--blue {path!r} is a checkpoint, but no policy loader is installed; "
            "install the trainers with: pip install 'neuronsmae[train]'"
        )
    return loaders[0].load()(path)


def play(blue: str, red: str, episodes: int, seed: int, **options: Any) -> dict[str, Any]:
    """Play ``episodes`` and return the counts, rates and 95% intervals."""
    policy = None
    if blue in LEVEL_NAMES:
        arena = Arena(seed=seed, mode="bots", blue_level=blue, **options)
    else:
        policy = load_policy(blue)
        arena = Arena(seed=seed, **(policy.options | options))
    outcomes: Counter[str] = Counter()
    try:
        for i in range(episodes):
            obs = arena.reset({"level": red}, seed=seed + i)
            if policy is not None:
                policy.reset()
            done, info = False, {}
            while not done:
                actions = (policy.act(obs, arena.get_avail_actions(), arena.get_state())
                           if policy is not None else [])
                obs, _, done, info = arena.step(actions)
            outcomes[str(info["winner"])] += 1
    finally:
        arena.close()
    return summarise(blue, red, outcomes, episodes, seed)


def summarise(blue: str, red: str, outcomes: Counter[str], n: int, seed: int) -> dict[str, Any]:
    """Rates and Wilson intervals from outcome counts."""
    out: dict[str, Any] = {"blue": blue, "red": red, "episodes": n, "seed": seed}
    for key, name in (("blue", "blue_win_rate"), ("red", "red_win_rate"), ("draw", "draw_rate")):
        out[name] = outcomes[key] / n if n else 0.0
        out[name.replace("rate", "ci95")] = list(wilson(outcomes[key], n))
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point."""
    parser = argparse.ArgumentParser(prog="neuronsmae-match", description=__doc__.split("\n")[0])
    parser.add_argument("--blue", default="hard",
                        help=f"bot level {LEVEL_NAMES} or a checkpoint path")
    parser.add_argument("--red", default="easy", choices=LEVEL_NAMES, help="red bot level")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    args = parser.parse_args(argv)
    if args.blue not in LEVEL_NAMES and not Path(args.blue).exists():
        parser.error(f"--blue must be one of {LEVEL_NAMES} or an existing checkpoint path")
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    result = play(args.blue, args.red, args.episodes, args.seed)
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"blue={result['blue']} vs red={result['red']}: {args.episodes} episodes, "
          f"seeds {args.seed}..{args.seed + args.episodes - 1}")
    for label, key in (("blue wins", "blue_win"), ("red wins", "red_win"), ("draws", "draw")):
        lo, hi = result[f"{key}_ci95"]
        print(f"  {label:9s} {result[f'{key}_rate']:.3f}  (95% CI {lo:.3f}-{hi:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
