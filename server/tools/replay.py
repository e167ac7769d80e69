"""``neuronsmae-replay``: re-simulate a recorded episode, check every decision, draw it.

    neuronsmae-replay FILE [--gif OUT.gif] [--mp4 OUT.mp4] [--fps 5] [--every 1] [--scale 1]

The recording (see :mod:`neuronsmae.protocol.recording`; written by the client's
``Recorder`` or ``neuronsmae-match --record``) is played again in an in-process ``Arena``
built from its seed and options, and every decision's hash is compared with the recorded
one. Why re-simulate rather than store frames: the file stays a few kilobytes, and a replay
that matches is proof that the simulation is deterministic for that episode — a mismatch
names the first decision that differs.

Exit status: 0 when every decision matches, 1 on the first mismatch, 2 when the file cannot
be read, the arguments are wrong, or a video needs a missing package.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import (
    InvalidActionError,
    InvalidOptionError,
    NeuronsMAEError,
    ReplayMismatchError,
)
from neuronsmae.protocol.recording import Recording, decision_hash, read_recording
from neuronsmae.server.arena import Arena
from neuronsmae.server.tools.video import (
    DEFAULT_FPS,
    FPS_RANGE,
    SCALE_RANGE,
    check_video_options,
    check_writable,
    write_video,
)


@dataclass
class ReplayResult:
    """What a replay established."""

    decisions: int
    """Decisions re-simulated and matched."""
    complete: bool
    """Whether the recording reaches the end of its episode."""
    winner: str | None
    frames: list[np.ndarray] = field(default_factory=list)
    """One frame after reset and one per decision, when rendering was asked for."""


def _short(h: str) -> str:
    return h[:12]


def replay(rec: Recording, render: bool = False) -> ReplayResult:
    """Re-simulate ``rec`` and check it decision by decision.

    Raises ``ReplayMismatchError`` (with ``.decision``) at the first decision whose hash
    differs, or whose recorded actions the arena refuses; decision 0 is the reset.
    """
    arena = Arena(seed=rec.arena_seed, **rec.options)
    frames: list[np.ndarray] = []
    try:
        arena.reset(rec.contexts, seed=rec.seed)
        got = decision_hash(arena.get_state())
        if got != rec.reset_hash:
            raise ReplayMismatchError(
                f"decision 0 (the reset) differs: recorded {_short(rec.reset_hash)}, "
                f"replayed {_short(got)}; the seed, contexts or options do not reproduce it",
                0,
            )
        if render:
            frames.append(arena.render())
        for k, d in enumerate(rec.decisions, start=1):
            try:
                _, rewards, done, _ = arena.step(d.actions)
            except InvalidActionError as exc:
                raise ReplayMismatchError(
                    f"decision {k}: the arena refuses the recorded actions {d.actions}: {exc}", k
                ) from exc
            got = decision_hash(arena.get_state(), rewards, done)
            if got != d.hash:
                raise ReplayMismatchError(
                    f"decision {k} differs: recorded {_short(d.hash)} (rewards {d.rewards}, "
                    f"done {d.done}), replayed {_short(got)} (rewards {list(rewards)}, "
                    f"done {done}); actions {d.actions}",
                    k,
                )
            if render:
                frames.append(arena.render())
    finally:
        arena.close()
    return ReplayResult(len(rec.decisions), rec.complete, rec.winner, frames)


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="neuronsmae-replay",
        description="Re-simulate a recorded episode, check every decision's hash, and "
        "optionally write it as a GIF or MP4.",
    )
    p.add_argument("file", type=Path, help="a recording (*.jsonl.gz)")
    p.add_argument("--gif", type=Path, help="write the episode as this GIF")
    p.add_argument(
        "--mp4", type=Path, help="write it as this MP4 (needs: pip install 'neuronsmae[video]')"
    )
    p.add_argument(
        "--fps",
        type=float,
        default=DEFAULT_FPS,
        help=f"video frames per second, in [{FPS_RANGE[0]:g}, {FPS_RANGE[1]:g}] "
        f"({DEFAULT_FPS:g}: twice real time)",
    )
    p.add_argument("--every", type=int, default=1, help="keep every n-th frame, n ≥ 1 (1)")
    p.add_argument(
        "--scale",
        type=float,
        default=1.0,
        help=f"resize frames by this factor, in [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}] (1)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Replay, write the videos; return the summary (raises on any failure)."""
    for out in (args.gif, args.mp4):
        if out is not None:
            check_writable(out)
    rec = read_recording(args.file)
    result = replay(rec, render=bool(args.gif or args.mp4))
    summary: dict[str, Any] = {
        "file": str(args.file), "ok": True, "decisions": result.decisions,
        "complete": result.complete, "winner": result.winner, "seed": rec.seed,
        "videos": {},
    }  # fmt: skip
    for out in (args.gif, args.mp4):
        if out is not None:
            path = write_video(out, result.frames, args.fps, args.every, args.scale)
            summary["videos"][str(path)] = path.stat().st_size
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:  # refused before the replay, video or not, so a bad flag never waits for one
        check_video_options(args.fps, args.every, args.scale)
    except InvalidOptionError as exc:
        parser.error(f"--{str(exc).replace('; ', '; --')}")
    try:
        summary = run(args)
    except ReplayMismatchError as exc:
        if args.json:
            print(
                json.dumps(
                    {
                        "file": str(args.file),
                        "ok": False,
                        "decision": exc.decision,
                        "error": str(exc),
                    }
                )
            )
        print(f"neuronsmae-replay: {args.file}: MISMATCH at {exc}", file=sys.stderr)
        return 1
    except (NeuronsMAEError, OSError) as exc:
        print(f"neuronsmae-replay: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(summary))
        return 0
    state = "complete" if summary["complete"] else "cut short"
    print(
        f"{args.file}: {summary['decisions']} decisions replayed identically "
        f"(seed {summary['seed']}, episode {state}, winner {summary['winner']})"
    )
    for path, size in summary["videos"].items():
        print(f"  wrote {path} ({size / 1024:.0f} KiB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
