"""A run directory's saved state: the checkpoint a run resumes from, its replay, and the
best-validated weights.

Every file is in the checkpoint format of trainers/core/checkpoint.py (the run's config,
arena, agent spec, counters and RNG beside the learner's state), so ``neuronsmae-match``
loads ``checkpoint.pt`` and ``best.pt`` alike. A resume reads the checkpoint back, then the
replay written at the same episode count, then ``best.pt`` if it was chosen at or before
that count (a later one is set aside: the stretch after the checkpoint is trained again).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from threading import Lock
from typing import Any

import numpy as np
import torch

from neuronsmae.trainers.core.checkpoint import (
    CHECKPOINT_NAME,
    REPLAY_NAME,
    CheckpointError,
    Counters,
    load_checkpoint,
    load_replay,
    policy_weights,
    save_checkpoint,
    save_replay,
)
from neuronsmae.trainers.core.learner import AgentSpec, EnvSpec
from neuronsmae.trainers.run.config import ConfigError, TrainConfig, check_resumable, make_config

BEST_NAME = "best.pt"
"""File name of the best-validated weights inside the run directory (checkpoint format)."""

log = logging.getLogger(__name__)


def resumable(run_dir: Path, cfg: TrainConfig) -> dict[str, Any]:
    """The checkpoint ``cfg`` resumes from, refused if its settings differ where a resume
    keeps them (as ``neuronsmae-train`` checks) or if its run has nothing left to do."""
    payload = load_checkpoint(run_dir / CHECKPOINT_NAME)
    check_resumable(make_config(payload["config"]), cfg)
    done = payload["counters"]["episodes"]
    if payload.get("finished") and done >= cfg.episodes:
        raise ConfigError(
            f"{run_dir} finished its {done} episodes and its final evaluation: "
            f"raise --episodes above {done} to train it further"
        )
    return payload


def load_learner(learner: Any, payload: dict[str, Any], run_dir: Path) -> None:
    """Load a checkpoint's learner state, naming the checkpoint when the networks differ."""
    try:
        learner.load_state_dict(payload["learner"])
    except (RuntimeError, KeyError, ValueError) as err:  # torch's mismatch report
        first = str(err).strip().splitlines()[0]
        raise CheckpointError(
            f"{run_dir / CHECKPOINT_NAME}: its networks do not fit this config ({first}); "
            "a resumed run keeps the settings in trainers.config.FIXED_ON_RESUME"
        ) from err


def saved_best(run_dir: Path, done: int) -> tuple[dict[str, np.ndarray], dict[str, Any]] | None:
    """The acting weights of ``best.pt`` and the validation row that chose them, if it was
    chosen at or before ``done`` episodes; one chosen later is moved aside and ignored."""
    best = run_dir / BEST_NAME
    if not best.is_file():
        return None
    chosen = load_checkpoint(best)
    at = chosen["selection"]["episodes"]
    if at <= done:
        return policy_weights(chosen["learner"]), chosen["selection"]
    aside = best.with_name(f"{BEST_NAME}.after-checkpoint")
    best.replace(aside)
    log.warning("%s was chosen at %d episodes, after the checkpoint's %d: moved to %s",
                best, at, done, aside.name)  # fmt: skip
    return None


@dataclass
class RunSaver:
    """Writes a run's checkpoint-format files and its replay into ``run_dir``."""

    run_dir: Path
    cfg: TrainConfig
    env: EnvSpec
    spec: AgentSpec
    replay_saved_at: int | None = None
    """The episode count of the replay on disk (a checkpoint at the same count, e.g. the
    finished one or one for new best weights, does not write it again)."""

    def save(
        self,
        name: str,
        learner_state: dict[str, Any],
        counters: Counters,
        np_rng: np.random.Generator,
        **extra: Any,
    ) -> None:
        """``<run_dir>/<name>``: the run's config, arena, spec, counters and RNG with
        ``learner_state`` and ``extra``."""
        save_checkpoint(
            self.run_dir / name,
            config=self.cfg.to_dict(),
            env=self.env,
            spec=self.spec,
            learner_state=learner_state,
            counters=counters,
            np_rng=np_rng,
            **extra,
        )

    def save_best(
        self,
        learner_state: dict[str, Any],
        weights: dict[str, np.ndarray],
        selection: dict[str, Any],
        counters: Counters,
        np_rng: np.random.Generator,
    ) -> None:
        """``best.pt``: the chosen acting weights in place of the learner's (its other state
        is the current one: a run resumes from ``checkpoint.pt``), and the row that chose them."""
        state = {**learner_state, "agent": {k: torch.as_tensor(v) for k, v in weights.items()}}
        self.save(BEST_NAME, state, counters, np_rng, selection=selection)

    def save_replay(self, buffer: Any, episodes: int, lock: Lock) -> None:
        """The replay at ``episodes``, once per count, under the learner's buffer lock
        (written after the checkpoint: a resume checks that the two counts match)."""
        if not self.cfg.eval.save_replay or self.replay_saved_at == episodes:
            return
        with lock:
            save_replay(self.run_dir / REPLAY_NAME, buffer, episodes)
        self.replay_saved_at = episodes

    def load_replay(self, buffer: Any, episodes: int) -> None:
        """Refill ``buffer`` from the replay saved at ``episodes``; without it, or with one
        saved at another count, the buffer refills from empty (logged)."""
        unloaded = load_replay(self.run_dir / REPLAY_NAME, buffer, episodes)
        if unloaded:
            log.warning("replay not restored (%s): it refills from empty", unloaded)
        else:
            self.replay_saved_at = episodes
            log.info("replay: %d items restored", len(buffer))
