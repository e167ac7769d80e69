"""Replay of training starts the team did not win: a simple form of level replay.

Why: a start (the reset seed: spawn poses and the bot's draws) decides much of a game
against the easy bot. The agents lose the starts they already judge bad (measured: 19 of 22
test losses of a default run fell in the lowest two fifths of the agents' own value of the
start, ``python -m bench.outcomes RUN_DIR/checkpoint.pt --episodes 200``), but uniform
seeds give those starts only their share of the data. Prioritized Level Replay (Jiang,
Grefenstette and Rocktäschel, ICML 2021) samples procedurally generated levels again in
proportion to how much there is left to learn on them; here the signal is the outcome
itself: a start the team did not win is queued, and with probability ``p`` a new training
episode replays one of the queued starts, drawn uniformly, instead of a fresh seed. A start
leaves the queue when it is won or has been played ``max_plays`` times (some starts are
lost by every policy), and the queue keeps only the ``capacity`` most recently lost starts,
so it follows the current policy.

Replays are training episodes like any other (same ε, stored in the buffer); every seed is
still a training seed, so the validation and test splits are untouched.
"""

from __future__ import annotations

from collections import OrderedDict
from typing import Any

import numpy as np

_STREAM = 0x5EED
"""Second word of this object's RNG seed, so its draws never share a stream with the
trainer's replay sampling."""


class StartReplay:
    """Chooses each training episode's reset seed: fresh, or a recently lost start."""

    def __init__(self, probability: float, max_plays: int, capacity: int, seed: int) -> None:
        if not (0.0 <= probability <= 1.0 and max_plays >= 2 and capacity >= 1):
            raise ValueError(
                f"StartReplay needs probability in [0, 1], max_plays ≥ 2 and capacity ≥ 1, got "
                f"{probability!r}, {max_plays!r} and {capacity!r}"
            )
        self.probability, self.max_plays, self.capacity = probability, max_plays, capacity
        self.rng = np.random.default_rng([seed, _STREAM])
        self.queued: OrderedDict[int, int] = OrderedDict()
        """Lost starts waiting for a replay: seed → plays so far, oldest first."""
        self.out: dict[int, int] = {}
        """Replays in flight: seed → plays before this one (a queued start is never issued
        twice at once)."""
        self.replays = 0
        """Replays issued so far."""

    @property
    def enabled(self) -> bool:
        """Whether any episode can be a replay (with p = 0 nothing is tracked or drawn, so
        a run without replay keeps exactly its former random streams)."""
        return self.probability > 0.0

    def choose(self, fresh: int) -> int:
        """The seed of the next training episode: ``fresh`` or a queued lost start."""
        if not self.enabled or not self.queued or self.rng.random() >= self.probability:
            return fresh
        seed = list(self.queued)[int(self.rng.integers(len(self.queued)))]
        self.out[seed] = self.queued.pop(seed)
        self.replays += 1
        return seed

    def record(self, seed: int, won: bool) -> None:
        """Note the outcome of a finished training episode played from ``seed``."""
        if not self.enabled:
            return
        plays = self.out.pop(seed, 0) + 1
        if won or plays >= self.max_plays:
            return
        self.queued[seed] = plays
        self.queued.move_to_end(seed)
        while len(self.queued) > self.capacity:
            self.queued.popitem(last=False)

    def state_dict(self) -> dict[str, Any]:
        """Queue, counters and RNG as plain values (checkpoint-safe). Replays in flight are
        saved as queued: a resumed run has none in flight."""
        queued = {**self.queued, **self.out}
        return {
            "seeds": [int(s) for s in queued],
            "plays": [int(p) for p in queued.values()],
            "replays": self.replays,
            "rng": self.rng.bit_generator.state,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` saved."""
        self.queued = OrderedDict(zip(state["seeds"], state["plays"], strict=True))
        self.out = {}
        self.replays = int(state["replays"])
        self.rng.bit_generator.state = state["rng"]
