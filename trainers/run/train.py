"""The training loop: sample episodes with Ray workers, learn, evaluate, record, checkpoint.

Two loops share everything but the order of sampling and learning:

* asynchronous (default): ``pipeline`` chunks of requests (one episode per arena of the
  worker) stay queued per worker; whenever episodes land they go to the buffer, and every
  ``train_every`` episodes the learner runs ``updates_per_round`` updates and broadcasts
  the new weights. Nobody waits for the slowest worker, and no wait outlasts the budget.
* synchronous (``sync=True``, the paper's loop): each iteration asks every worker for one
  episode, waits for all, then learns.

Training episode ``k`` is reset with a seed derived from the run seed and ``k`` that is
always below ``eval_seed``. Periodic greedy evaluations (the validation split) use
``eval_seed, eval_seed+1, ...`` and the final one (the test split) starts at
``eval_seed + TEST_SEED_OFFSET``: the win rate is measured on starts the agents never trained
on, and the reported one on starts that did not pick the best weights either.

The task comes from the ``arena`` group and the networks are sized from the workers'
``get_env_info()`` (trainers/play/task.py). With ``opponent`` set, each training episode's red is
drawn from a pool of bots, checkpoints and snapshots of the learner (trainers/play/pool.py,
trainers/run/competition.py); evaluations always play the ``level`` bot.
"""

from __future__ import annotations

import json
import logging
import os
import random
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np
import ray
import torch

from neuronsmae.protocol import EnvInfo, InvalidContextError
from neuronsmae.protocol.contexts import check_contexts
from neuronsmae.protocol.errors import ClosedError
from neuronsmae.protocol.levels import level_from_arg
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import REPLAYS, Episode, ReplayMemoryError
from neuronsmae.trainers.core.checkpoint import CHECKPOINT_NAME, Counters, restore_rng
from neuronsmae.trainers.core.learner import (
    DeviceError,
    EnvSpec,
    agent_spec,
    resolve_device,
)
from neuronsmae.trainers.core.symmetry import parse_generators, task_group
from neuronsmae.trainers.play.evaluate import summarize
from neuronsmae.trainers.play.rollout import Request
from neuronsmae.trainers.play.task import blue_view
from neuronsmae.trainers.run import marl_eval
from neuronsmae.trainers.run.competition import Competition
from neuronsmae.trainers.run.config import ConfigError, TrainConfig
from neuronsmae.trainers.run.config_groups import (
    TEST_SEED_OFFSET,
    WIN_RULES,
    resolve_learner,
)
from neuronsmae.trainers.run.contexts import ContextSpec
from neuronsmae.trainers.run.experimental import StartReplay
from neuronsmae.trainers.run.interrupt import POLL_SECONDS, StopSignals, TrainingInterrupted
from neuronsmae.trainers.run.learning import Learning, make_learner
from neuronsmae.trainers.run.placement import sampler_placement, start_ray
from neuronsmae.trainers.run.records import Recorder, RunLock, check_new_run_dir, trim_records
from neuronsmae.trainers.run.sampler import Sampler
from neuronsmae.trainers.run.saving import (
    RunSaver,
    load_learner,
    resumable,
    saved_best,
)

log = logging.getLogger(__name__)

Hook = Callable[["Trainer"], None]
"""Called after every batch of landed episodes (tests use it to inject faults)."""


def train_seed(run_seed: int, k: int, eval_seed: int) -> int:
    """Reset seed of training episode ``k``: deterministic and always below ``eval_seed``."""
    return (run_seed * 1_000_003 + k) % eval_seed


class Trainer:
    """One training run: owns the sampler, learner, buffer, records and counters."""

    def __init__(self, cfg: TrainConfig, *, resume: bool = False, hook: Hook | None = None) -> None:
        self.cfg, self.hook = cfg, hook
        self.run_dir = cfg.run_dir
        self.counters = Counters()
        self.np_rng = np.random.default_rng(cfg.seed)
        self.learning: Learning | None = None
        """The learner's side: the Q-learner, its replay and batches (set by ``_build``)."""
        exp = cfg.experimental
        self.starts = StartReplay(
            exp.start_replay, exp.start_replay_plays, exp.start_replay_capacity, cfg.seed
        )
        random.seed(cfg.seed)
        torch.manual_seed(cfg.seed)
        cores = os.cpu_count() or 1
        if cfg.torch_threads > cores:
            raise ConfigError(
                f"torch_threads={cfg.torch_threads}: the learner's machine has {cores} cores; "
                f"give 1 to {cores}"
            )
        torch.set_num_threads(cfg.torch_threads)
        try:
            self.device = resolve_device(cfg.learner.device)
            """Where the learner runs (``learner.device``, resolved before anything starts)."""
        except DeviceError as err:
            raise ConfigError(str(err)) from None
        self.competition = Competition(cfg)
        self.mode = "competitive" if self.competition.competitive else "cooperative"
        """The arenas' mode: competitive once a policy may play red (a bot then plays red
        through the ``bot_team`` context)."""
        self.opponent: dict[str, Any] = {"level": level_from_arg(cfg.level)}
        """The contexts of every evaluation: red's ``level`` bot."""
        if self.competition.competitive:
            self.opponent["bot_team"] = "red"
        self.train_contexts = ContextSpec.parse(cfg.contexts)
        """Each training episode's further contexts, drawn per episode."""
        self.eval_contexts = {
            name: {**self.opponent, **spec.value()}
            for name, spec in cfg.eval.context_specs().items()
        }
        """Every evaluation's contexts by name: ``main`` (validation and test), then the
        extra test sets."""
        self.best: tuple[dict[str, np.ndarray], dict[str, Any]] | None = None
        """Acting weights of the best validation evaluation, and that evaluation's row."""
        self.stop = StopSignals()
        """Turns Ctrl-C or SIGTERM into a stop request while :meth:`run` runs."""
        self._check_contexts(workers=False)
        self.resumed_steps: int | None = None
        """A resumed run's env steps at its checkpoint (TensorBoard hides what came after)."""
        self.recorder: Recorder | None = None
        self.closed = False
        """Set by :meth:`close`: a trainer runs once."""
        self.lock = RunLock(self.run_dir)
        try:
            saved = resumable(self.run_dir, cfg) if resume else None
            if not resume:
                check_new_run_dir(self.run_dir)
        except BaseException:
            self.lock.release()
            raise
        self.owns_ray = not ray.is_initialized()
        try:
            if self.owns_ray:
                start_ray(cfg)
            self._build(cfg)
            if saved is not None:
                self._resume(saved)
        except BaseException:
            self.close()
            raise
        self.recent: deque[Episode] = deque(maxlen=100)
        self.evals: list[dict[str, Any]] = []
        self.stored_seeds: list[int] = []
        """Reset seeds of the stored training episodes, in arrival order (for tests)."""
        self.seen_restarts = 0

    def _build(self, cfg: TrainConfig) -> None:
        """Start the workers, then size the networks and the buffer from their env."""
        n_workers, base_seed = cfg.n_workers(), cfg.seed * 1000
        self.sampler = Sampler(
            n_workers,
            env_kind=cfg.env,
            base_seed=base_seed,
            base_port=cfg.cluster.base_port,
            envs_per_worker=cfg.envs_per_worker,
            groups=cfg.cluster.groups if cfg.env == "remote" else 1,
            servers_per_worker=cfg.cluster.servers_per_worker,
            worker_cpus=cfg.cluster.worker_cpus,
            max_failures=cfg.cluster.max_worker_failures,
            **sampler_placement(cfg, n_workers, base_seed, cfg.arena.arena_options(self.mode)),
        )
        self._check_contexts()
        info = blue_view(EnvInfo.from_dict(self.sampler.env_info()))
        self.info = info
        """The task from the learning team's side (its agents are blue's)."""
        self.lcfg = lc = resolve_learner(cfg.learner, info, cfg.arena.observability,
                                         cfg.arena.spawn)  # fmt: skip
        """The learner settings with every ``auto`` made concrete for this task."""
        self.env = EnvSpec.of(info, lc.features)
        self.spec = agent_spec(
            self.env, lc.agent_hidden, lc.last_action_input, lc.agent_id_input, lc.features,
            lc.head, info, lc.agent_net, lc.action_masks == "env",
        )  # fmt: skip
        self.competition.load_fixed(info)
        self.learner = make_learner(self.env, self.spec, cfg.alg, cfg.learner, self.device)
        group = task_group(parse_generators(lc.augment), lc.features, info)
        env, size = self.env, cfg.learner.buffer_size
        try:
            self.buffer = REPLAYS[lc.replay](size, env.n_agents, env.obs_dim, env.state_dim,
                                             env.n_actions, env.episode_limit)  # fmt: skip
        except ReplayMemoryError as err:
            raise ConfigError(f"learner.buffer_size={cfg.learner.buffer_size}: {err}") from err
        self.learning = Learning(cfg.learner, self.learner, self.buffer, group, self.np_rng,
                                 cfg.seed)  # fmt: skip
        self.saver = RunSaver(self.run_dir, cfg, self.env, self.spec)
        """Writes the checkpoint, the replay and the best weights."""

    def _check_contexts(self, workers: bool = True) -> None:
        """Check every value the contexts can take against the protocol's table (before any
        worker starts), then reset a worker's arenas with them (``workers``), so a key or a
        range the arena refuses stops the run now rather than mid-way."""
        sets = [{**self.opponent, **x} for x in self.train_contexts.extremes()]
        sets += [
            {**self.opponent, **self.competition.contexts(m)} for m in self.competition.pool.fixed
        ]
        sets += list(self.eval_contexts.values())
        try:
            for contexts in sets:
                check_contexts(contexts)
            if workers:
                self.sampler.check_contexts(sets)
        except InvalidContextError as err:
            raise ConfigError(f"contexts: {err}") from err

    def _resume(self, payload: dict[str, Any]) -> None:
        load_learner(self.learner, payload, self.run_dir)
        self.counters = Counters(**payload["counters"])
        restore_rng(payload["rng"], self.np_rng)
        done = self.counters.episodes
        self.saver.load_replay(self.buffer, done)
        if payload.get("starts") is not None:
            self.starts.load_state_dict(payload["starts"])
        self.competition.resume(payload.get("opponents"))
        if self.cfg.eval.keep_best:
            self.best = saved_best(self.run_dir, done)
        dropped = trim_records(self.run_dir, done, redo_final=done >= self.cfg.episodes)
        log.info("resumed %s at %d episodes (%d record rows after the checkpoint dropped)",
                 self.run_dir, done, dropped)  # fmt: skip
        self.resumed_steps = self.counters.env_steps

    def close(self) -> None:
        """Stop the learner's thread, the workers, and Ray too if this trainer started it."""
        if self.learning is not None:
            self.learning.close()
        if getattr(self, "sampler", None) is not None:
            self.sampler.close()
        if self.owns_ray and ray.is_initialized():
            ray.shutdown()
        self.lock.release()
        self.closed = True

    # --- the loop ----------------------------------------------------------------------
    def run(self) -> dict[str, Any]:
        """Train until ``cfg.episodes``, then evaluate greedily; return the final figures.
        A trainer runs once: its workers are gone afterwards (``ClosedError``)."""
        if self.closed:
            raise ClosedError(
                "this Trainer has run or been closed: build a new one for a new run, or "
                "Trainer(cfg, resume=True) to continue this one"
            )
        cfg = self.cfg
        try:
            (self.run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2))
            self.recorder = Recorder(
                self.run_dir, cfg.episodes, self.counters.episodes, cfg.progress,
                cfg.max_minutes * 60, self.resumed_steps,
            )  # fmt: skip
            self._start_session()
            with self.stop:
                self._run_sync() if cfg.sync else self._run_async()
            self.learning.end(self.counters)
            self.checkpoint()
            if self.stop.requested:
                raise TrainingInterrupted(self.run_dir, self.counters.episodes, self.stop.requested)
            final = self.evaluate(self.cfg.eval.final_eval_episodes, split="test")
            extra = {
                name: self.evaluate(cfg.eval.final_eval_episodes, "test", contexts=name)
                for name in list(self.eval_contexts)[1:]
            }
            best = self._evaluate_best()
            self.checkpoint(finished=True)
            marl_eval.write(self.run_dir)
        finally:
            if self.recorder is not None:
                self.recorder.close()
            self.close()
        return {
            "final": final,
            "extra_tests": extra,
            "best": best,
            "evals": self.evals,
            "counters": asdict(self.counters),
            "start_replays": self.starts.replays,
            "run_dir": str(self.run_dir),
        }

    def _start_session(self) -> None:
        """This session's clocks, and the workers' first weights and opponents."""
        self.session_start = time.perf_counter()
        self.session_steps = 0
        self.wall_base = self.counters.wall_seconds
        self.learning.begin(self.counters)
        self.sampler.broadcast(self._policy())
        if self.competition.pool.snapshot_due(0, 0):  # the first snapshot: the start weights
            self._snapshot()
        elif self.competition.pool.has_policies:
            self.sampler.broadcast_opponents(self.competition.policies())

    def _more(self) -> bool:
        """Episodes left to play, in this session wall-clock budget left, and no stop asked."""
        left = self._seconds_left()
        more = self.counters.episodes < self.cfg.episodes and (left is None or left > 0)
        return more and not self.stop.requested

    def _seconds_left(self) -> float | None:
        """Wall-clock budget left in this session (None: no time budget)."""
        limit = self.cfg.max_minutes * 60.0
        if limit <= 0:
            return None
        return limit - (time.perf_counter() - self.session_start)

    def _run_async(self) -> None:
        cfg, issued = self.cfg, self.counters.episodes
        while self._more():
            self.learning.check()
            while (
                self.sampler.idle_slots() > 0
                and issued < cfg.episodes
                and not self.learning.throttled()
            ):
                # One episode per arena; near the end of the budget, shared among workers.
                share = -(-(cfg.episodes - issued) // self.sampler.n_live)
                n = min(cfg.envs_per_worker, share)
                self.sampler.submit([self._request(issued + j) for j in range(n)])
                issued += n
            left = self._seconds_left()
            wait = POLL_SECONDS if left is None else min(max(left, 0.0), POLL_SECONDS)
            landed = self.sampler.wait(timeout=wait)
            if landed:
                self._absorb(landed)
            elif not self.sampler.in_flight:  # nothing out: the learner is what lags
                self.learning.catch_up(wait)

    def _run_sync(self) -> None:
        while self._more():
            k = self.counters.episodes
            n = min(self.cfg.iteration_size(self.sampler.n_live), self.cfg.episodes - k)
            self._absorb(
                self.sampler.run([self._request(k + j) for j in range(n)], self._seconds_left())
            )

    def _request(self, k: int) -> Request:
        cfg = self.cfg
        eps = cfg.epsilon(k)
        seed = self.starts.choose(train_seed(cfg.seed, k, cfg.eval.eval_seed))
        contexts = {**self.opponent, **self.train_contexts.sample(cfg.seed, k)}
        if not self.competition.enabled:
            return Request(seed, eps, contexts)
        member = self.competition.pool.draw(k)
        contexts.update(self.competition.contexts(member))
        return Request(seed, eps, contexts, opponent=member.id)

    def _absorb(self, episodes: list[Episode]) -> None:
        """Store landed episodes, then learn, evaluate and checkpoint as they fall due."""
        cfg, c = self.cfg, self.counters
        before = c.episodes
        for episode in episodes:
            self.learning.store(episode)
            self.stored_seeds.append(episode.info["seed"])
            self.starts.record(episode.info["seed"], episode.info.get("winner") == "blue")
            self.recent.append(episode)
            c.episodes += 1
            self.recorder.episode(c.episodes, episode.info, episode.total_reward, episode.length)
            c.env_steps += episode.length
            self.session_steps += episode.length
        c.restarts += self.sampler.restarts - self.seen_restarts
        self.seen_restarts = self.sampler.restarts
        c.wall_seconds = self.wall_base + time.perf_counter() - self.session_start
        rounds = self._rounds_due(before, c.episodes)
        if self.learning.learn(rounds, c):
            self.sampler.broadcast(self._policy())
        if self.competition.pool.snapshot_due(before, c.episodes):
            self._snapshot()
        self.recorder.advance(c.episodes - before, time.perf_counter() - self.session_start)
        if rounds:
            self.recorder.train(self._train_row())
        # No periodic evaluation once the budget (episodes or minutes) is spent: the final
        # one follows at once, and a wall-clock budget must not be overrun by a validation.
        if (
            cfg.eval.eval_every
            and c.episodes // cfg.eval.eval_every > before // cfg.eval.eval_every
            and self._more()
        ):
            self.evaluate()
        if c.episodes // cfg.eval.checkpoint_every > before // cfg.eval.checkpoint_every:
            self.checkpoint()
        if self.hook is not None:
            self.hook(self)

    def _rounds_due(self, before: int, after: int) -> int:
        if self.cfg.sync:
            return 1
        every = self.cfg.learner.train_every
        return after // every - before // every

    def _snapshot(self) -> None:
        """Add the learner's acting weights to the pool and hand the workers the pool's
        policies anew."""
        self.competition.snapshot(
            self.counters.episodes, self._policy(), self.env, self.counters, self.np_rng
        )
        self.sampler.broadcast_opponents(self.competition.policies())

    # --- records -----------------------------------------------------------------------
    def _policy(self) -> Policy:
        return Policy(self.spec, self.learning.acting_weights())

    def _train_row(self) -> dict[str, Any]:
        c, recent = self.counters, list(self.recent)
        elapsed = max(time.perf_counter() - self.session_start, 1e-9)
        return {
            **asdict(c),
            "epsilon": self.cfg.epsilon(c.episodes),
            "train_win_rate": summarize(recent)["win_rate"] if recent else 0.0,
            "train_return": summarize(recent)["mean_return"] if recent else 0.0,
            "env_steps_per_s": self.session_steps / elapsed,
            **self.learning.last_stats,
        }

    def evaluate(
        self,
        episodes: int | None = None,
        split: str = "validation",
        weights: str = "latest",
        policy: Policy | None = None,
        contexts: str = "main",
    ) -> dict[str, Any]:
        """Greedy win rate of ``policy`` (default: the learner's latest weights) on held-out
        seeds; recorded and returned.

        ``split`` picks the seeds (``validation`` or ``test``, see the module docstring);
        ``contexts`` names the fixed evaluation contexts (``main``, or an extra test set of
        ``eval.extra_test_contexts``). With ``keep_best``, a validation result better than
        every earlier one keeps the weights that earned it. Training requests queued
        afterwards act with the latest weights again; those already in flight keep the
        weights they were sent with.
        """
        cfg, c = self.cfg, self.counters
        n = episodes or cfg.eval.eval_episodes
        first = cfg.eval.eval_seed + (TEST_SEED_OFFSET if split == "test" else 0)
        evaluated = policy or self._policy()
        self.sampler.broadcast(evaluated)
        context = self.eval_contexts[contexts]
        requests = [Request(first + k, 0.0, context, "eval") for k in range(n)]
        figures = summarize(self.sampler.run(requests))
        self.sampler.broadcast(self._policy())
        c.wall_seconds = self.wall_base + time.perf_counter() - self.session_start
        row = {**asdict(c), **figures, "split": split, "weights": weights, "contexts": contexts}
        self.recorder.eval(row)
        self.evals.append(row)
        # On a tie the later weights win: they trained longer, and a 50-episode validation
        # figure cannot tell two equal readings apart anyway.
        figure = WIN_RULES[cfg.eval.win_rule]
        better = self.best is None or row[figure] >= self.best[1][figure]
        if split == "validation" and cfg.eval.keep_best and better:
            self.best = (evaluated.weights, row)
            self.checkpoint()  # first: best.pt never runs ahead of the point a resume takes
            state = self.learning.state_dict()
            self.saver.save_best(state, evaluated.weights, row, c, self.np_rng)
        return row

    def _evaluate_best(self) -> dict[str, Any] | None:
        """The best-validated weights on the test seeds (None without ``keep_best``)."""
        if self.best is None:
            return None
        weights, chosen = self.best
        best = Policy(self.spec, weights)
        row = self.evaluate(
            self.cfg.eval.final_eval_episodes, split="test", weights="best", policy=best
        )
        return {**row, "chosen_at_episodes": chosen["episodes"], "validation": chosen}

    def checkpoint(self, finished: bool = False) -> None:
        """Save the learner, counters and RNG states to ``<run_dir>/checkpoint.pt``, then the
        replay (``finished``: after the final evaluation)."""
        c, learning = self.counters, self.learning
        self.saver.save(
            CHECKPOINT_NAME, learning.state_dict(), c, self.np_rng,
            starts=self.starts.state_dict(), opponents=self.competition.state_dict(),
            finished=finished,
        )  # fmt: skip
        self.saver.save_replay(self.buffer, c.episodes, learning.buffer_lock)


def train(cfg: TrainConfig, *, resume: bool = False, hook: Hook | None = None) -> dict[str, Any]:
    """Run one training to completion and return its final greedy evaluation and history."""
    return Trainer(cfg, resume=resume, hook=hook).run()
