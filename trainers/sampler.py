"""Ray sampling: rollout workers as actors, weights by the object store, fault tolerance.

The learner puts the agent's weights into the object store once per update (``ray.put``)
and every episode request carries that reference, so the weights travel once per update,
not once per request. Finished episodes are collected with ``ray.wait``: the learner takes
whatever has landed and never waits for the slowest worker (asynchronous mode), or it asks
every worker for one episode and waits for them all (:meth:`Sampler.run`, the paper's
synchronous loop and evaluation).

A worker whose env or process dies is killed and started again under the same index; the
request it was serving is sent again to the new actor, and since a worker only returns
*finished* episodes, the partial one is never seen. A worker that keeps failing is given up
after ``max_failures`` consecutive failures; the run stops only when no worker is left.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import ray
from ray.exceptions import RayError

from neuronsmae.trainers.buffer import Episode
from neuronsmae.trainers.placement import ServerPool
from neuronsmae.trainers.rollout import Policy, RolloutWorker

log = logging.getLogger(__name__)


class NoWorkersLeftError(RuntimeError):
    """Every worker failed more often in a row than allowed."""


@dataclass(frozen=True)
class Request:
    """One episode to play: which seed, at which ε, and what it is for."""

    seed: int
    """Reset seed of the episode."""
    epsilon: float
    """Exploration rate (0 for greedy evaluation)."""
    kind: str = "train"
    """``train`` (goes to the buffer) or ``eval`` (only counted)."""


@dataclass
class _Task:
    worker: int
    generation: int
    request: Request


def _cause(err: BaseException) -> str:
    """The root error of a Ray failure: the last line of its remote traceback."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return lines[-1] if lines else type(err).__name__


class Sampler:
    """A pool of ``RolloutWorker`` Ray actors, each owning its own environment."""

    def __init__(
        self,
        n_workers: int,
        *,
        env_kind: str,
        base_seed: int,
        base_port: int,
        contexts: Mapping[str, Any],
        worker_cpus: float,
        env_options: Mapping[str, Any] | None = None,
        max_failures: int = 5,
        pipeline: int = 2,
        worker_resources: Mapping[str, float] | None = None,
        servers: ServerPool | None = None,
    ) -> None:
        self.env_kind, self.contexts = env_kind, dict(contexts)
        self.base_seed, self.base_port = base_seed, base_port
        self.env_options = dict(env_options or {})
        self.max_failures, self.pipeline = max_failures, pipeline
        self.servers = servers
        """Server actors the workers connect to (None: each worker's env finds its own)."""
        self.actor_cls = ray.remote(
            num_cpus=worker_cpus, resources=dict(worker_resources or {}), max_restarts=0
        )(RolloutWorker)
        self.actors: list[Any | None] = [self._spawn(i) for i in range(n_workers)]
        self.generation = [0] * n_workers
        self.failures = [0] * n_workers
        self.restarts = 0
        self.in_flight: dict[Any, _Task] = {}
        self.landed: list[Episode] = []
        self.weights_ref: Any = None
        self.version = -1

    def _spawn(self, i: int) -> Any:
        options = self.env_options
        if self.servers is not None:  # point worker i at its (live) server actor
            options = {**options, **self.servers.env_options(i)}
        return self.actor_cls.remote(
            i, self.env_kind, self.base_seed + i, self.base_port + i, options
        )

    def env_info(self) -> dict[str, Any]:
        """``get_env_info()`` of the first live worker's environment."""
        while True:
            i = self._live()[0]
            try:
                return ray.get(self.actors[i].env_info.remote())
            except RayError as err:
                self._fail(i, self.generation[i], err)

    @property
    def n_live(self) -> int:
        """Workers still in service."""
        return len(self._live())

    def _live(self) -> list[int]:
        live = [i for i, a in enumerate(self.actors) if a is not None]
        if not live:
            raise NoWorkersLeftError("every rollout worker failed repeatedly; see the log")
        return live

    def broadcast(self, policy: Policy) -> None:
        """Put a new policy in the object store once; later requests pass its reference."""
        self.weights_ref = ray.put(policy)
        self.version += 1

    def submit(self, request: Request, worker: int | None = None) -> None:
        """Queue one episode on a worker (the least loaded live one by default)."""
        live = self._live()
        if worker is None or self.actors[worker] is None:
            load = {i: 0 for i in live}
            for task in self.in_flight.values():
                load[task.worker] = load.get(task.worker, 0) + 1
            worker = min(live, key=lambda i: load[i])
        ref = self.actors[worker].run_episode.remote(
            self.weights_ref, self.version, request.epsilon, request.seed, self.contexts
        )
        self.in_flight[ref] = _Task(worker, self.generation[worker], request)

    def idle_slots(self) -> int:
        """Requests that can be queued to keep ``pipeline`` per live worker in flight."""
        return self.pipeline * self.n_live - len(self.in_flight)

    def wait(self, timeout: float | None = None, kind: str = "train") -> list[Episode]:
        """Return the finished episodes of ``kind`` that landed, waiting for at least one."""
        while True:
            taken = [e for e in self.landed if e.info["kind"] == kind]
            if taken:
                self.landed = [e for e in self.landed if e.info["kind"] != kind]
                return taken
            if not any(t.request.kind == kind for t in self.in_flight.values()):
                return []
            ready, _ = ray.wait(list(self.in_flight), num_returns=1, timeout=timeout)
            if not ready:
                return []
            for ref in ready:
                self._harvest(ref)

    def _harvest(self, ref: Any) -> None:
        task = self.in_flight.pop(ref)
        try:
            episode: Episode = ray.get(ref)
        except RayError as err:
            self._fail(task.worker, task.generation, err)
            self.submit(task.request, task.worker)  # the same episode again, on a fresh actor
            return
        self.failures[task.worker] = 0
        episode.info["kind"] = task.request.kind
        self.landed.append(episode)

    def _fail(self, i: int, generation: int, err: BaseException) -> None:
        """Restart worker ``i`` (once per generation), or give it up after too many failures."""
        if generation != self.generation[i] or self.actors[i] is None:
            return  # another request already reported this actor's death
        self.failures[i] += 1
        log.warning(
            "rollout worker %d failed (%d in a row): %s",
            i,
            self.failures[i],
            _cause(err),
        )
        ray.kill(self.actors[i], no_restart=True)
        self.generation[i] += 1
        if self.failures[i] >= self.max_failures:
            log.error("giving up rollout worker %d after %d failures", i, self.failures[i])
            self.actors[i] = None
            return
        time.sleep(min(0.25 * 2 ** (self.failures[i] - 1), 8.0))  # let a server come back
        self.actors[i] = self._spawn(i)
        self.restarts += 1

    def run(self, requests: Sequence[Request]) -> list[Episode]:
        """Play all ``requests`` spread over the workers and wait for every one of them.

        Episodes of other kinds that land meanwhile are kept for the next :meth:`wait`.
        """
        kind = requests[0].kind if requests else "eval"
        live = self._live()
        for j, request in enumerate(requests):
            self.submit(request, live[j % len(live)])
        out: list[Episode] = []
        while len(out) < len(requests):
            got = self.wait(kind=kind)
            if not got and not any(t.request.kind == kind for t in self.in_flight.values()):
                break
            out.extend(got)
        return sorted(out, key=lambda e: e.info["seed"])

    def close(self) -> None:
        """Close every worker's env, then stop the actors.

        Closing first releases a server that outlives the run (``neuronsmae-serve``, a
        router) at once; killed without it, the server stays owned until its lease ends
        and the next run's workers are refused with ``BusyError`` meanwhile.
        """
        live = [actor for actor in self.actors if actor is not None]
        with contextlib.suppress(RayError):  # a dead or stuck worker: killed just below
            ray.get([actor.close.remote() for actor in live], timeout=5.0)
        for actor in live:
            ray.kill(actor, no_restart=True)
        self.actors = [None] * len(self.actors)
        self.in_flight.clear()
        if self.servers is not None:
            self.servers.close()
