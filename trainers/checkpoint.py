"""Checkpoints: everything a run needs to resume, loadable with ``weights_only=True``.

A checkpoint holds only tensors and plain Python values (config as a dict, counters, RNG
states as tuples and dicts), so ``torch.load(path, weights_only=True)`` reads it: loading a
checkpoint never executes pickled code. It is written to a temporary file and renamed, so a
run killed while saving leaves the previous checkpoint intact. The replay buffer is not
saved (hundreds of MB for little benefit); a resumed run refills it before learning again.
"""

from __future__ import annotations

import os
import random
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol.errors import NeuronsMAEError
from neuronsmae.trainers.learner import AgentSpec, EnvSpec

CHECKPOINT_NAME = "checkpoint.pt"
"""File name of a run's latest checkpoint inside its run directory."""
FORMAT = 2
"""Bumped when the layout changes incompatibly (2: the nested training config, and agent
specs that carry the environment's layout)."""


class CheckpointError(NeuronsMAEError, ValueError):
    """A file given as a checkpoint is not one this version reads: not a torch file, not
    loadable with ``weights_only=True`` (it would run pickled code), or another format."""

    code = "invalid_checkpoint"


class MissingCheckpointError(CheckpointError, FileNotFoundError):
    """No checkpoint where one was expected (a run stopped before its first one, or a
    mistyped path)."""

    code = "missing_checkpoint"


@dataclass
class Counters:
    """Progress of a run, carried across ``--resume``."""

    episodes: int = 0
    """Training episodes stored in the buffer."""
    env_steps: int = 0
    """Decisions taken in those episodes."""
    updates: int = 0
    """Gradient updates."""
    wall_seconds: float = 0.0
    """Training wall time over all sessions of the run."""
    restarts: int = 0
    """Rollout-worker restarts over all sessions."""


def policy_weights(learner_state: dict[str, Any]) -> dict[str, np.ndarray]:
    """The agent's weights in a saved learner state, as NumPy arrays."""
    return {k: v.numpy() for k, v in learner_state["agent"].items()}


def checkpoint_path(path: str | os.PathLike[str]) -> Path:
    """A checkpoint file from either its own path or its run directory."""
    p = Path(path)
    return p / CHECKPOINT_NAME if p.is_dir() else p


def save_checkpoint(
    path: Path,
    *,
    config: dict[str, Any],
    env: EnvSpec,
    spec: AgentSpec,
    learner_state: dict[str, Any],
    counters: Counters,
    np_rng: np.random.Generator,
    selection: dict[str, Any] | None = None,
    starts: dict[str, Any] | None = None,
    opponents: dict[str, Any] | None = None,
    finished: bool = False,
) -> None:
    """Write the checkpoint atomically (temporary file, then rename).

    ``learner_state`` is ``QLearner.state_dict()``: its ``agent`` entry is what acting needs.
    ``selection`` is the evaluation that chose these weights (for ``best.pt``).
    ``starts`` is the start replay's state (``StartReplay.state_dict()``) and ``opponents``
    the opponent pool's (its snapshots), for ``--resume``. ``finished``: written after the
    run's final evaluation (a resumed run that was not finished evaluates again).
    """
    payload = {
        "format": FORMAT,
        "config": config,
        "env": asdict(env),
        "agent_spec": asdict(spec),
        "learner": learner_state,
        "counters": asdict(counters),
        "selection": selection,
        "starts": starts,
        "opponents": opponents,
        "finished": finished,
        "rng": {
            "torch": torch.get_rng_state(),
            "numpy": np_rng.bit_generator.state,
            "python": random.getstate(),
        },
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)


def load_checkpoint(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a checkpoint (file or run directory) with ``weights_only=True``."""
    p = checkpoint_path(path)
    if not p.is_file():
        raise MissingCheckpointError(f"no checkpoint at {p}")
    try:
        payload = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch reports a bad file as any of several error types
        raise CheckpointError(
            f"{p} is not a NeuronsMAE checkpoint: torch.load(weights_only=True) cannot read "
            f"it ({type(exc).__name__}); give a checkpoint.pt, best.pt or snapshot written by "
            "neuronsmae-train, or its run directory"
        ) from exc
    found = payload.get("format") if isinstance(payload, dict) else None
    if found != FORMAT:
        raise CheckpointError(f"{p} has checkpoint format {found}, not {FORMAT}")
    return payload


def restore_rng(rng_state: dict[str, Any], np_rng: np.random.Generator) -> None:
    """Put the learner process's random generators back where the checkpoint left them."""
    torch.set_rng_state(rng_state["torch"])
    np_rng.bit_generator.state = rng_state["numpy"]
    version, internal, gauss = rng_state["python"]
    random.setstate((version, tuple(internal), gauss))
