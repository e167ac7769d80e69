"""The learner's side of a training run: the Q-learner, its replay, the batches it draws.

:class:`Learning` is what the trainer's loop hands episodes to and asks for weights. It
learns either inline — ``updates_in_round`` updates every ``train_every`` episodes, each
batch drawn, augmented and sent to the learner's device in a background thread while the
previous one trains — or, with ``learner.replay_ratio`` > 0, in a thread of its own
(:class:`~neuronsmae.trainers.run.decoupled.LearnerThread`) while the loop goes on
sampling. Every read of the learner's state (acting weights, checkpoints) and every write
to the replay takes a lock, so the two threads never see each other half-way.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any

import numpy as np
import torch

from neuronsmae.trainers.core.buffer import Batch, Episode, prefetch_pays, prefetched
from neuronsmae.trainers.core.checkpoint import Counters
from neuronsmae.trainers.core.learner import (
    AgentSpec,
    EnvSpec,
    QLearner,
    resolve_device,
)
from neuronsmae.trainers.core.mixers import mixer_for_algorithm
from neuronsmae.trainers.core.symmetry import augment
from neuronsmae.trainers.run.config_groups import LearnerConfig
from neuronsmae.trainers.run.decoupled import LearnerThread


def make_learner(
    env: EnvSpec, spec: AgentSpec, alg: str, cfg: LearnerConfig, device: torch.device | None = None
) -> QLearner:
    """The learner of algorithm ``alg`` (its mixer by name) with the ``learner`` group's
    settings, on ``device`` (default: ``cfg.device`` resolved here)."""
    device = resolve_device(cfg.device) if device is None else device
    per_update = cfg.target_update_unit == "updates"
    return QLearner(
        env, spec, mixer_for_algorithm(alg), lr=cfg.lr, gamma=cfg.gamma,
        grad_clip=cfg.grad_clip,
        target_update_interval=cfg.target_update_interval if per_update else None,
        double_q=cfg.double_q, mixer_embed=cfg.mixer_embed,
        hypernet_hidden=cfg.hypernet_hidden, td_lambda=cfg.td_lambda,
        hypernet_layers=cfg.hypernet_layers, mixer_state=cfg.mixer_state,
        mask_destroyed=cfg.mask_destroyed, device=device,
    )  # fmt: skip


class Learning:
    """The learner, its replay and the symmetry ``group`` batches are augmented with."""

    def __init__(
        self, cfg: LearnerConfig, learner: QLearner, buffer: Any, group: Any,
        rng: np.random.Generator, seed: int,
    ) -> None:  # fmt: skip
        self.cfg, self.learner, self.buffer, self.group = cfg, learner, buffer, group
        self.rng, self.seed = rng, seed
        self.lock = threading.Lock()
        """Held while the learner's state is updated or read."""
        self.buffer_lock = threading.Lock()
        """Held while the replay is written or drawn from."""
        self.thread: LearnerThread | None = None
        """The learner's own thread (``replay_ratio`` > 0), while a session runs."""
        self.last_stats: dict[str, float] = {}
        self.session_episodes, self.learn_base, self.weights_at = 0, 0.0, 0
        self.background = prefetch_pays(cfg.prefetch, learner.device)
        """Whether inline rounds draw their next batch in a background thread."""

    # --- episodes and batches -------------------------------------------------------------
    def store(self, episode: Episode) -> None:
        with self.buffer_lock:
            self.buffer.add(episode)

    def next_batch(self, rng: np.random.Generator | None = None) -> Batch:
        """A batch drawn and augmented with ``rng`` (the run's generator by default), on the
        learner's device."""
        rng = self.rng if rng is None else rng
        with self.buffer_lock:
            batch = self.buffer.sample(self.cfg.batch_size, rng)
        return augment(batch, self.group, rng).to(self.learner.device)

    # --- a session ------------------------------------------------------------------------
    def begin(self, counters: Counters) -> None:
        """A session starts: the learner's own thread too, when decoupled."""
        self.session_episodes, self.learn_base = counters.episodes, counters.learn_seconds
        self.weights_at = self.learner.updates
        if self.cfg.replay_ratio > 0:
            own = np.random.default_rng([self.seed, counters.episodes, 1])
            self.thread = LearnerThread(
                self.learner, lambda: self.next_batch(own), ratio=self.cfg.replay_ratio,
                tolerance=self.cfg.replay_tolerance, learning_starts=self.cfg.learning_starts,
                lock=self.lock,
            )  # fmt: skip
            self.thread.start()

    def learn(self, rounds: int, counters: Counters) -> bool:
        """After episodes were stored: ``rounds`` rounds of updates inline (once enough are
        stored), or the decoupled thread told what is stored. True when the workers should
        get new weights."""
        if self.thread is not None:
            return self._keep_up(counters)
        if not rounds or len(self.buffer) < self.cfg.learning_starts:
            return False
        start = time.perf_counter()
        for _ in range(rounds):
            self._round(counters)
        counters.learn_seconds += time.perf_counter() - start
        return True

    def throttled(self) -> bool:
        """Sampling waits: the decoupled learner lags its replay ratio."""
        return self.thread is not None and self.thread.behind()

    def catch_up(self, timeout: float) -> None:
        """Wait (without polling) for a lagging decoupled learner, at most ``timeout``."""
        if self.thread is not None and self.thread.behind():
            self.thread.catch_up(timeout)

    def check(self) -> None:
        """Re-raise what stopped the decoupled learner, if anything did."""
        if self.thread is not None:
            self.thread.check()

    def end(self, counters: Counters) -> None:
        """End the learner's thread (after its update in hand) and take its last counters."""
        if self.thread is None:
            return
        self.thread.stop()
        self._count(counters)
        self.thread = None

    def close(self) -> None:
        """Stop the learner's thread, if it runs (its error was raised in the run)."""
        if self.thread is not None:
            with contextlib.suppress(RuntimeError):
                self.thread.stop()
            self.thread = None

    # --- reading the learner --------------------------------------------------------------
    def acting_weights(self) -> dict[str, np.ndarray]:
        with self.lock:
            return self.learner.acting_weights()

    def state_dict(self) -> dict[str, Any]:
        with self.lock:
            return self.learner.state_dict()

    # --- inside ---------------------------------------------------------------------------
    def _round(self, counters: Counters) -> None:
        """One round of updates (``updates_in_round`` of them, from what is stored); the
        targets are copied after its first update when ``refreshes_targets`` says so for
        this round."""
        refresh = self.cfg.refreshes_targets(counters.rounds)
        batches = prefetched(self.next_batch, self.cfg.updates_in_round(len(self.buffer)),
                             self.background)  # fmt: skip
        for u, batch in enumerate(batches):
            self.last_stats = self.learner.train(batch)
            if refresh and u == 0:
                self.learner.update_targets()
        counters.rounds += 1
        counters.updates, counters.samples = self.learner.updates, self.learner.samples

    def _keep_up(self, counters: Counters) -> bool:
        """Tell the thread what is stored, take its counters; True once it has made a
        round's worth of updates since the weights the workers last got."""
        assert self.thread is not None
        self.thread.stored(counters.episodes - self.session_episodes)
        self.thread.check()
        self._count(counters)
        self.last_stats = self.thread.last_stats
        if counters.updates - self.weights_at >= self.cfg.updates_per_round * self.cfg.train_every:
            self.weights_at = counters.updates
            return True
        return False

    def _count(self, counters: Counters) -> None:
        assert self.thread is not None
        counters.updates, counters.samples = self.learner.updates, self.learner.samples
        counters.learn_seconds = self.learn_base + self.thread.busy_seconds
