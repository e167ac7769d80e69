"""``neuronsmae-match``: play bots (or trained policies) against each other and score them.

    neuronsmae-match --blue hard --red easy --episodes 200 --seed 0 [--json]
                     [--record DIR] [--gif OUT.gif]

``--blue`` and ``--red`` take a bot level: the released build's ``0`` and ``1``, the paper's
``easy``, ``middle``, ``hard``, or ``random``, ``middle_spread``, ``hard_flank`` (the table is
in docs/contexts.md, "Bots"). ``--blue`` may also be a path to a trained checkpoint: the
policy is loaded through the ``neuronsmae.policies`` entry-point group (the trainers register
theirs), so the server package never imports the trainers. Episode ``i`` uses seed
``seed + i``, so two runs with the same arguments give the same numbers. ``--record DIR``
writes every episode as a replayable recording
(``neuronsmae-replay``); ``--gif OUT`` draws the first episode.
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

from neuronsmae.protocol.errors import InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg
from neuronsmae.protocol.recording import (
    SUFFIX,
    Decision,
    Recording,
    RecordingWriter,
    decision_hash,
)
from neuronsmae.server.arena import Arena
from neuronsmae.server.tools.video import write_video

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


def _recording(
    arena: Arena, record: Path, i: int, seed: int, contexts: dict[str, Any], meta: dict[str, Any]
) -> RecordingWriter:
    """Start the file of episode ``i`` (just reset with ``seed`` and ``contexts``)."""
    rec = Recording(
        arena.seed,
        arena.config.to_dict(),
        seed,
        contexts,
        decision_hash(arena.get_state()),
        meta=meta,
    )
    return RecordingWriter(record / f"episode_{i:05d}_s{seed}{SUFFIX}", rec)


def play(
    blue: str,
    red: str,
    episodes: int,
    seed: int,
    *,
    record: Path | None = None,
    gif: Path | None = None,
    **options: Any,
) -> dict[str, Any]:
    """Play ``episodes`` and return the counts, rates and 95% intervals.

    ``record``: a directory to write every episode's recording to; ``gif``: a file to draw
    the first episode in (one frame per decision). ``blue`` and ``red`` are levels as typed
    on the command line (:data:`LEVEL_ARGS`: "0" and "1" are the released levels); ``blue``
    may be a checkpoint path instead.
    """
    policy = None
    if blue in LEVEL_ARGS:
        arena = Arena(seed=seed, mode="bots", blue_level=level_from_arg(blue), **options)
    else:
        policy = load_policy(blue)
        arena = Arena(seed=seed, **(policy.options | options))
    outcomes: Counter[str] = Counter()
    writer: RecordingWriter | None = None
    try:
        for i in range(episodes):
            contexts = {"level": level_from_arg(red)}
            obs = arena.reset(contexts, seed=seed + i)
            if policy is not None:
                policy.reset()
            if record is not None:
                writer = _recording(
                    arena, record, i, seed + i, contexts, {"blue": blue, "red": red}
                )
            frames = [arena.render()] if gif is not None and i == 0 else None
            done, info = False, {}
            while not done:
                actions = (
                    policy.act(obs, arena.get_avail_actions(), arena.get_state())
                    if policy is not None
                    else []
                )
                obs, rewards, done, info = arena.step(actions)
                if writer is not None:
                    writer.decision(Decision.after(actions, arena.get_state(), rewards, done, info))
                if frames is not None:
                    frames.append(arena.render())
            if writer is not None:
                writer.close()
            if frames is not None and gif is not None:
                write_video(gif, frames)
            outcomes[str(info["winner"])] += 1
    finally:
        if writer is not None:
            writer.close()
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
    parser.add_argument(
        "--blue", default="hard", help=f"bot level {list(LEVEL_ARGS)} or a checkpoint path"
    )
    parser.add_argument("--red", default="easy", choices=LEVEL_ARGS, help="red bot level")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print one JSON object")
    parser.add_argument(
        "--record",
        type=Path,
        metavar="DIR",
        help="write every episode's recording here (see neuronsmae-replay)",
    )
    parser.add_argument("--gif", type=Path, metavar="OUT", help="draw the first episode as a GIF")
    args = parser.parse_args(argv)
    if args.blue not in LEVEL_ARGS and not Path(args.blue).exists():
        parser.error(f"--blue must be one of {list(LEVEL_ARGS)} or an existing checkpoint path")
    if args.episodes < 1:
        parser.error("--episodes must be at least 1")
    if args.gif is not None and args.gif.suffix.lower() != ".gif":
        parser.error("--gif must name a .gif file")
    try:
        result = play(
            args.blue, args.red, args.episodes, args.seed, record=args.record, gif=args.gif
        )
    except (NeuronsMAEError, OSError) as exc:
        print(f"neuronsmae-match: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
        return 0
    print(
        f"blue={result['blue']} vs red={result['red']}: {args.episodes} episodes, "
        f"seeds {args.seed}..{args.seed + args.episodes - 1}"
    )
    for label, key in (("blue wins", "blue_win"), ("red wins", "red_win"), ("draws", "draw")):
        lo, hi = result[f"{key}_ci95"]
        print(f"  {label:9s} {result[f'{key}_rate']:.3f}  (95% CI {lo:.3f}-{hi:.3f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
