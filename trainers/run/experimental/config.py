"""The settings of the experiments (:mod:`neuronsmae.trainers.run.experimental`)."""

from __future__ import annotations

from dataclasses import dataclass

from neuronsmae.trainers.checks import ConfigError, check_types


@dataclass(frozen=True)
class ExperimentalConfig:
    """Experiments off by default; ``TrainConfig.experimental``."""

    start_replay: float = 0.0
    """Probability in [0, 1] that a training episode replays a recent start the team did not
    win instead of a fresh seed (0: never, the paper's uniform starts); see
    trainers/run/experimental/starts.py. The agents lose mostly the starts they already judge
    bad, and uniform seeds give those starts only their small share of the data (what it
    was measured to do: docs/lab/results-log.md)."""
    start_replay_plays: int = 3
    """A lost start is played at most this many times in all (≥ 2), so unwinnable starts
    leave."""
    start_replay_capacity: int = 256
    """Lost starts kept for replay (≥ 1), the most recent ones (the queue follows the
    policy)."""

    def __post_init__(self) -> None:
        check_types(self)
        if not 0.0 <= self.start_replay <= 1.0:
            raise ConfigError(f"start_replay must lie in [0, 1] (0 = off), got {self.start_replay}")
        if self.start_replay_plays < 2 or self.start_replay_capacity < 1:
            raise ConfigError(
                "start_replay_plays must be ≥ 2 (a first play and a replay) and "
                f"start_replay_capacity ≥ 1, got {self.start_replay_plays} and "
                f"{self.start_replay_capacity}"
            )
