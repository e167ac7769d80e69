"""The trainer's side of a competitive run: the pool's policies, snapshots written and read
back, and each training episode's opponent.

:class:`Competition` owns the run's :class:`~neuronsmae.trainers.play.pool.OpponentPool`. It
loads the fixed checkpoints (checking that each fits red's side of the task), writes every
snapshot of the learner as a checkpoint-format file under ``<run_dir>/snapshots/`` (the
match and league commands load them), hands the workers the policies the draw may pick
whenever they change, and restores all of it on ``--resume``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.protocol.levels import level_from_arg
from neuronsmae.protocol.policies import layout_differences
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.checkpoint import CheckpointError, Counters, save_checkpoint
from neuronsmae.trainers.core.learner import EnvSpec
from neuronsmae.trainers.play.evaluate import load_policy
from neuronsmae.trainers.play.pool import Member, OpponentPool
from neuronsmae.trainers.run.config import ConfigError, TrainConfig

log = logging.getLogger(__name__)


def check_fits(policy: Policy, side: EnvInfo, name: str) -> None:
    """Raise :class:`ConfigError` unless ``policy`` was built for ``side``'s layout (the
    observation and action layout of one team), naming what differs."""
    differ = layout_differences(policy.spec.env_info, side.to_dict())
    if policy.spec.n_actions != side.n_actions:
        differ.append(f"n_actions: {policy.spec.n_actions} ≠ {side.n_actions}")
    if differ:
        raise ConfigError(
            f"{name} was trained on another task layout than this one "
            f"({'; '.join(sorted(set(differ)))}): give the run the arena options it was "
            "trained with"
        )


class Competition:
    """The pool of a run with ``opponent`` set (see the module docstring)."""

    def __init__(self, cfg: TrainConfig) -> None:
        self.cfg, self.run_dir = cfg, cfg.run_dir
        self.pool = OpponentPool(cfg.opponent, cfg.selfplay, cfg.seed)
        self.competitive = self.pool.has_policies
        """Whether a policy may play red: the arenas then run in competitive mode."""
        self._fixed = {m.id: _opponent(m.value) for m in self.pool.fixed if m.kind == "ckpt"}
        """The fixed checkpoints, read now: a missing or unreadable one stops the run before
        Ray starts."""

    @property
    def enabled(self) -> bool:
        return self.pool.enabled

    def load_fixed(self, side: EnvInfo) -> None:
        """Give the pool every fixed checkpoint, checking it fits red's side."""
        for member in self.pool.fixed:
            if member.kind == "ckpt":
                policy = self._fixed[member.id]
                check_fits(policy, side, f"opponent checkpoint {member.value}")
                self.pool.weights[member.id] = policy

    def contexts(self, member: Member) -> dict[str, Any]:
        """The reset contexts that put ``member`` on red."""
        if not self.competitive:  # bots only: red is the arena's bot, named by level
            return {"level": level_from_arg(member.value)}
        return member.contexts()

    def snapshot(
        self,
        episodes: int,
        policy: Policy,
        env: EnvSpec,
        counters: Counters,
        np_rng: np.random.Generator,
    ) -> None:
        """Take the learner's acting weights as a snapshot: written to its file (checkpoint
        format, the learner state holding the agent only), added to the pool."""
        member = self.pool.add_snapshot(episodes, policy)
        save_checkpoint(
            self.pool.snapshot_path(self.run_dir, member),
            config=self.cfg.to_dict(),
            env=env,
            spec=policy.spec,
            learner_state={"agent": {k: torch.as_tensor(v) for k, v in policy.weights.items()}},
            counters=counters,
            np_rng=np_rng,
        )
        log.info("snapshot %s: %d in the window", member.id, len(self.pool.window()))

    def policies(self) -> dict[str, Policy]:
        """The policies the draw may pick (what the workers need)."""
        return self.pool.policies()

    def state_dict(self) -> dict[str, Any]:
        return self.pool.state_dict()

    def resume(self, state: Mapping[str, Any] | None) -> None:
        """Restore the snapshots recorded in a checkpoint, reading each from its file."""
        if not state:
            return
        policies = dict(self.pool.weights)
        for episodes in state.get("snapshots", []):
            member = Member(f"self:{episodes}")
            path = self.pool.snapshot_path(self.run_dir, member)
            if not Path(path).is_file():
                raise ConfigError(f"resume: snapshot {path} is missing")
            policies[member.id] = load_policy(path)
        self.pool.load_state_dict(state, policies)


def _opponent(path: str) -> Policy:
    """An ``opponent`` entry's checkpoint, or a :class:`CheckpointError` naming the entry."""
    try:
        return load_policy(path)
    except CheckpointError as err:
        raise type(err)(f"opponent entry {path!r}: {err}") from None
