"""``Recorder``: wrap any arena and write each episode to a replayable file as it is played.

    env = Recorder(Arena(seed=0), "replays/")          # or Recorder(RM(seed=0), ...)
    obs = env.reset({"level": "hard"}, seed=42)        # use env exactly like the arena
    ...                                                # replays/episode_00000_s42.jsonl.gz

The file (format in :mod:`neuronsmae.protocol.recording`) holds the arena's seed and
options, the episode's seed and contexts, every action and a hash of every decision's
outcome; ``neuronsmae-replay FILE --gif OUT.gif`` re-simulates it, checks every hash and
draws it. The wrapper is an :class:`~neuronsmae.protocol.interface.ArenaAPI` itself, so it
drops in wherever an arena is used (rollout workers, Gymnasium and PettingZoo faces).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.interface import Action, ArenaAPI, inherit_docstrings
from neuronsmae.protocol.messages import MAX_SEED
from neuronsmae.protocol.recording import (
    Decision,
    Recording,
    RecordingWriter,
    decision_hash,
    existing_recordings,
    recording_name,
    to_plain,
)
from neuronsmae.protocol.wrappers import ArenaWrapper

Select = Callable[[int, Mapping[str, Any] | None], bool]
"""``select(seed, contexts)``: whether to record the episode about to start."""


def arena_identity(env: ArenaAPI) -> tuple[int, dict[str, Any]]:
    """The ``(seed, options)`` that rebuild ``env`` as an in-process ``Arena``.

    Read from an ``Arena`` (``seed``, ``config.to_dict()``), an ``RM`` (``seed``,
    ``options``) or another ``Recorder``; anything else must be told.
    """
    seed = getattr(env, "seed", None)
    config = getattr(env, "config", None)
    options = config.to_dict() if hasattr(config, "to_dict") else getattr(env, "options", None)
    if not isinstance(seed, (int, np.integer)) or not isinstance(options, Mapping):
        raise InvalidOptionError(
            f"Recorder cannot tell how to rebuild a {type(env).__name__}: pass "
            "arena_seed= and options= (the Arena(seed, **options) that plays the same)"
        )
    return int(seed), dict(options)


def _check_settings(arena_seed: Any, limit: Any, prefix: Any) -> None:
    """Refuse a seed outside an arena's range, a negative or non-integer ``limit`` and a
    ``prefix`` that is not a plain file-name start (a path would write outside out_dir)."""
    integer = isinstance(arena_seed, (int, np.integer)) and not isinstance(arena_seed, bool)
    if not integer or not 0 <= int(arena_seed) <= MAX_SEED:
        raise InvalidOptionError(
            f"arena_seed must be an integer in [0, {MAX_SEED}], got {arena_seed!r}"
        )
    if limit is not None and (isinstance(limit, bool) or not isinstance(limit, int) or limit < 0):
        raise InvalidOptionError(f"limit must be None or an integer ≥ 0, got {limit!r}")
    if not isinstance(prefix, str) or any(c in prefix for c in "/\\\0") or ".." in prefix:
        raise InvalidOptionError(
            f"prefix must be the start of a file name (no '/', '\\' or '..'), got {prefix!r}"
        )


@inherit_docstrings
class Recorder(ArenaWrapper):
    """Records the episodes played through it, one file each, into ``out_dir``.

    ``select(seed, contexts)`` picks which episodes to record (default: all) and ``limit``
    caps how many; the others are played but not written. Files are named
    ``{prefix}{n:05d}_s{seed}.jsonl.gz`` (``n`` counts recorded episodes) and listed in
    :attr:`paths`; give each of several recorders sharing a directory its own ``prefix``.
    A directory that already holds files of the same series is refused (they would be
    overwritten), and no recording file is ever overwritten.

    One difference from the bare arena: ``reset(seed=None)`` resets with a seed drawn from
    the recorder's own generator (seeded by the arena's seed), because an episode that
    continues the arena's RNG could not be replayed from its file alone.
    """

    def __init__(
        self,
        env: ArenaAPI,
        out_dir: str | Path,
        *,
        arena_seed: int | None = None,
        options: Mapping[str, Any] | None = None,
        meta: Mapping[str, Any] | None = None,
        select: Select | None = None,
        limit: int | None = None,
        prefix: str = "episode_",
    ) -> None:
        if arena_seed is None or options is None:
            seed, opts = arena_identity(env)
            arena_seed = seed if arena_seed is None else arena_seed
            options = opts if options is None else options
        self.env = env
        self.out_dir = Path(out_dir)
        if self.out_dir.exists() and not self.out_dir.is_dir():
            raise InvalidOptionError(
                f"out_dir {str(out_dir)!r} exists and is not a directory; recordings go into a "
                "directory (created on the first recorded episode if missing)"
            )
        _check_settings(arena_seed, limit, prefix)
        found = existing_recordings(self.out_dir, prefix)
        if found:
            raise InvalidOptionError(
                f"out_dir {str(out_dir)!r} already holds {len(found)} recording(s) named "
                f"{prefix!r}... ({found[0].name}, ...): they would be overwritten; give another "
                "out_dir or prefix"
            )
        self.seed = int(arena_seed)
        self.options = to_plain(dict(options))
        self.meta = to_plain(dict(meta or {}))
        self.select = select
        self.limit = limit
        self.prefix = prefix
        self.paths: list[Path] = []
        """Every file written so far, in order."""
        self._seeds = np.random.default_rng(self.seed)
        self._writer: RecordingWriter | None = None

    # ---- recording ---------------------------------------------------------------------

    def _wanted(self, seed: int, contexts: Mapping[str, Any] | None) -> bool:
        if self.limit is not None and len(self.paths) >= self.limit:
            return False
        return self.select is None or bool(self.select(seed, contexts))

    def _finish(self) -> None:
        """Close the current file (complete, or cut short by a reset or close)."""
        writer, self._writer = self._writer, None
        if writer is not None:
            writer.close()

    # ---- ArenaAPI ----------------------------------------------------------------------

    def reset(
        self, contexts: Mapping[str, Any] | None = None, seed: int | None = None
    ) -> list[np.ndarray]:
        self._finish()
        if seed is None:
            seed = int(self._seeds.integers(2**31))
        obs = self.env.reset(contexts, seed=seed)
        if self._wanted(seed, contexts):
            rec = Recording(
                arena_seed=self.seed,
                options=self.options,
                seed=int(seed),
                contexts=None if contexts is None else to_plain(dict(contexts)),
                reset_hash=decision_hash(self.env.get_state()),
                meta=self.meta,
            )
            path = self.out_dir / recording_name(self.prefix, len(self.paths), seed)
            self._writer = RecordingWriter(path, rec)
            self.paths.append(path)
        return obs

    def step(
        self, actions: Sequence[Action]
    ) -> tuple[list[np.ndarray], list[float], bool, dict[str, Any]]:
        obs, rewards, done, info = self.env.step(actions)
        if self._writer is not None:
            self._writer.decision(
                Decision.after(actions, self.env.get_state(), rewards, done, info)
            )
            if done:
                self._finish()
        return obs, rewards, done, info

    def close(self) -> None:
        # The current file first (kept, cut short), then the wrapped arena.
        self._finish()
        self.env.close()

    def __getattr__(self, name: str) -> Any:
        """Anything else (``place``, ``agent_name``, ...) is the wrapped arena's."""
        if name == "env":  # not set yet: __init__ failed before it
            raise AttributeError(name)
        return getattr(self.env, name)


REPLAY = "neuronsmae.server.tools.replay:replay"
"""The server's re-simulation of a recording (``neuronsmae-replay``), opened by name."""
VIDEO = "neuronsmae.server.tools.video:write_video"
"""The server's frame writer (GIF, or MP4 with the ``video`` extra), opened by name."""


def write_replay_video(rec: Recording, path: str | Path) -> None:
    """Re-simulate ``rec`` in this process and write its rendered frames to ``path``.

    The simulation is the server's, reached by name as ``env="inprocess"`` reaches its
    arena (:func:`~neuronsmae.client.source.resolve`): the client imports no server module
    by itself."""
    from neuronsmae.client.source import resolve

    frames = resolve(REPLAY)(rec, render=True).frames
    resolve(VIDEO)(path, frames)
