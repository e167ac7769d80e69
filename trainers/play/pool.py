"""The opponent pool of a competitive run: bots, fixed checkpoints and snapshots of the
learner itself, and the rule that draws one per training episode.

``neuronsmae-train --opponent easy,runs/a/best.pt,self`` trains blue against a pool of
*members*: each bot level named, each checkpoint named, and with ``self`` the snapshots of
the learner's own acting weights, one taken when the run starts and one every
``selfplay.snapshot_every`` training episodes after.

The draw (:meth:`OpponentPool.draw`) is δ-uniform opponent sampling (Bansal, Pachocki,
Sidor, Sutskever and Mordatch, "Emergent Complexity via Multi-Agent Competition", ICLR
2018, "opponent sampling"): of the snapshots ``0 .. v`` taken so far, those from ``⌊δ·v⌋``
on are in the *window*, and the opponent is drawn uniformly from the fixed members and the
window's snapshots. δ = 0 draws from the whole history (fictitious self-play's average of
past policies, Heinrich, Lanctot and Silver, ICML 2015); δ = 1 plays the latest snapshot
only (plain self-play). Bansal et al. report that playing older versions too (δ < 1)
trains more robust agents than the latest alone; the default here, δ = 0.5, keeps the
newer half of the history. The
draw for training episode ``k`` uses a generator seeded by the run seed and ``k`` alone, so
in the synchronous loop (where the pool is a function of ``k``) a run and its resumed
continuation draw the same opponents. Evaluations always play the run's ``level`` bot.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg
from neuronsmae.trainers.checks import ConfigError, check_types

SELF = "self"
"""The ``--opponent`` entry that adds the learner's own snapshots to the pool."""
SNAPSHOT_DIR = "snapshots"
"""Snapshots are written to ``<run_dir>/snapshots/self_<episodes>.pt`` (checkpoint format:
``neuronsmae-match`` and ``neuronsmae-league`` load them)."""
_DRAW_SALT = 0x5E1F_9A7E
"""Separates the opponent draws from the other per-episode draws of the same run seed."""


@dataclass(frozen=True)
class Member:
    """One entry of the pool."""

    id: str
    """``bot:<level>``, ``ckpt:<path>`` or ``self:<episodes>`` (a snapshot taken after that
    many training episodes)."""

    @property
    def kind(self) -> str:
        return self.id.partition(":")[0]

    @property
    def value(self) -> str:
        return self.id.partition(":")[2]

    @property
    def is_policy(self) -> bool:
        """Whether the worker plays it (a checkpoint or a snapshot), not the arena's bot."""
        return self.kind != "bot"

    def contexts(self) -> dict[str, Any]:
        """The reset contexts that put this member on red in a competitive arena."""
        if self.kind == "bot":
            return {"level": level_from_arg(self.value), "bot_team": "red"}
        return {"bot_team": "none"}


def _exists(path: str) -> bool:
    """Whether ``path`` names a file or folder (False for a name the system cannot even
    look up, such as one too long)."""
    try:
        return Path(path).exists()
    except (OSError, ValueError):
        return False


def parse_opponents(text: str) -> tuple[list[Member], bool]:
    """``"easy,runs/a/best.pt,self"`` → the fixed members and whether ``self`` is in it."""
    fixed: list[Member] = []
    self_play = False
    entries = [part.strip() for part in text.split(",")] if text.strip() else []
    if "" in entries:
        raise ConfigError(f"opponent {text!r} has an empty entry between its commas")
    for entry in entries:
        if entry == SELF:
            if self_play:
                raise ConfigError(f"opponent {text!r} names a member twice ({SELF!r})")
            self_play = True
        elif entry in LEVEL_ARGS:
            fixed.append(Member(f"bot:{entry}"))
        elif _exists(entry):
            fixed.append(Member(f"ckpt:{entry}"))
        else:
            raise ConfigError(
                f"opponent entry {entry!r} is neither a bot level ({', '.join(LEVEL_ARGS)}), "
                f"{SELF!r}, nor an existing checkpoint file or run directory"
            )
    if len({m.id for m in fixed}) != len(fixed):
        raise ConfigError(f"opponent {text!r} names a member twice")
    return fixed, self_play


@dataclass(frozen=True)
class SelfPlayConfig:
    """Snapshots of the learner and the opponent draw (trainers/play/pool.py)."""

    snapshot_every: int = 500
    """Training episodes between snapshots of the learner's acting weights, ≥ 1, when
    ``opponent`` holds ``self`` (one is taken at the start too). In the synchronous loop
    make it a multiple of the iteration's episodes (the paper's 20: 500 = every 25
    iterations)."""
    delta: float = 0.5
    """δ of δ-uniform opponent sampling (Bansal et al. 2018) in [0, 1]: the window holds the
    snapshots from ⌊δ·v⌋ to the latest v; 0 is the whole history, 1 the latest only."""

    def __post_init__(self) -> None:
        check_types(self)
        if self.snapshot_every < 1:
            raise ConfigError(f"selfplay.snapshot_every must be ≥ 1, got {self.snapshot_every}")
        if not 0.0 <= self.delta <= 1.0:
            raise ConfigError(f"selfplay.delta must lie in [0, 1], got {self.delta}")


def window_start(n_snapshots: int, delta: float) -> int:
    """Index of the first snapshot in the window when ``n_snapshots`` exist (v = n − 1)."""
    return math.floor(delta * max(n_snapshots - 1, 0))


class OpponentPool:
    """The fixed members and the learner's snapshots; draws one member per episode."""

    def __init__(self, text: str, selfplay: SelfPlayConfig, seed: int) -> None:
        self.fixed, self.self_play = parse_opponents(text)
        self.selfplay, self.seed = selfplay, seed
        self.snapshots: list[Member] = []
        """Snapshots taken so far, oldest first."""
        self.weights: dict[str, Any] = {}
        """The acting policy of every policy member (checkpoints and snapshots) by id."""

    @property
    def enabled(self) -> bool:
        return bool(self.fixed) or self.self_play

    @property
    def has_policies(self) -> bool:
        """Whether a policy ever plays red (the arena then runs in competitive mode)."""
        return self.self_play or any(m.is_policy for m in self.fixed)

    def window(self) -> list[Member]:
        """The snapshots the draw may pick (see the module docstring)."""
        return self.snapshots[window_start(len(self.snapshots), self.selfplay.delta) :]

    def candidates(self) -> list[Member]:
        """Every member the next draw may pick, fixed members first."""
        return [*self.fixed, *self.window()]

    def draw(self, k: int) -> Member:
        """The opponent of training episode ``k``: uniform over :meth:`candidates`, from a
        generator seeded by the run seed and ``k``."""
        members = self.candidates()
        if not members:
            raise ConfigError("the opponent pool is empty: give --opponent members or 'self'")
        rng = np.random.default_rng([self.seed, k, _DRAW_SALT])
        return members[int(rng.integers(len(members)))]

    def snapshot_due(self, before: int, after: int) -> bool:
        """Whether a snapshot falls due as the episode count goes from ``before`` to
        ``after`` (and the first one, before any episode)."""
        if not self.self_play:
            return False
        if not self.snapshots:
            return True
        every = self.selfplay.snapshot_every
        return after // every > before // every

    def add_snapshot(self, episodes: int, policy: Any) -> Member:
        """Record the snapshot taken after ``episodes`` training episodes."""
        member = Member(f"self:{episodes}")
        self.snapshots.append(member)
        self.weights[member.id] = policy
        return member

    def policies(self) -> dict[str, Any]:
        """The policies of the members the draw may pick (what the workers need)."""
        return {m.id: self.weights[m.id] for m in self.candidates() if m.is_policy}

    def snapshot_path(self, run_dir: Path, member: Member) -> Path:
        """Where ``member``'s snapshot file lives."""
        return run_dir / SNAPSHOT_DIR / f"self_{int(member.value):08d}.pt"

    def state_dict(self) -> dict[str, Any]:
        """The pool's state for the checkpoint: the snapshots' episode counts."""
        return {"snapshots": [int(m.value) for m in self.snapshots]}

    def load_state_dict(self, state: Mapping[str, Sequence[int]], policies: Mapping[str, Any]
                        ) -> None:  # fmt: skip
        """Restore the snapshots (``policies``: the snapshot and checkpoint policies by id)."""
        self.snapshots = [Member(f"self:{e}") for e in state.get("snapshots", [])]
        missing = [m.id for m in [*self.snapshots, *self.fixed] if m.is_policy
                   and m.id not in policies]  # fmt: skip
        if missing:
            raise ConfigError(f"resume: no saved policy for opponent pool members {missing}")
        self.weights = dict(policies)
