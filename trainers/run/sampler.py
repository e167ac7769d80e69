"""Ray sampling: rollout workers as actors, weights by the object store, fault tolerance.

Each worker plays its requests on ``envs`` arenas at once (:mod:`.rollout`); a Ray call
hands it a *chunk* of episode requests and returns them all finished, so Ray's per-call
cost is paid once per many environment steps. The learner puts the agent's weights into
the object store once per update (``ray.put``) and every chunk carries that reference, so
the weights travel once per update, not once per request. Finished chunks are collected
with ``ray.wait``: the learner takes whatever has landed and never waits for the slowest
worker (asynchronous mode), or it hands out a set of requests and waits for all of them
(:meth:`Sampler.run`, the paper's synchronous loop and evaluation).

Placement is checked up front: every worker must be up within ``start_timeout`` seconds or
the sampler refuses at once with an error saying how many could not be placed, so a worker
count that the cluster cannot hold never turns into a wait without end. Every wait takes a
timeout.

A worker whose env or process dies is killed and started again under the same index; the
chunk it was serving is sent again to the new actor, and since a worker only returns
*finished* episodes, partial ones are never seen. A worker that keeps failing is given up
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
from ray.exceptions import GetTimeoutError, RayError

from neuronsmae.protocol import InvalidContextError
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.buffer import Episode
from neuronsmae.trainers.play.rollout import Request, RolloutWorker
from neuronsmae.trainers.run.placement import ServerPool

log = logging.getLogger(__name__)

START_TIMEOUT = 300.0
"""Seconds every worker may take to come up (Ray placement, imports, its server's start)."""


class NoWorkersLeftError(RuntimeError):
    """Every worker failed more often in a row than allowed."""


class PlacementError(RuntimeError):
    """Some workers could not be placed on the Ray cluster, or did not start in time."""


@dataclass
class _Task:
    worker: int
    generation: int
    requests: list[Request]
    opponents: tuple[Any, int] = (None, -1)
    """The opponents' reference and version the requests were drawn against (a chunk sent
    again after a failure keeps them, whatever the pool holds by then)."""


def check_capacity(need: Mapping[str, float], n_workers: int) -> None:
    """Refuse at once a worker count the Ray cluster can never hold: ``need`` (resource →
    total amount the workers ask for) beyond the cluster's totals. Resources other runs
    hold for a while are waited for instead (see ``start_timeout``)."""
    total = ray.cluster_resources()
    short = {k: (v, total.get(k, 0.0)) for k, v in need.items() if total.get(k, 0.0) < v - 1e-9}
    if short:
        said = ", ".join(
            f"{k}: {v:g} needed, {have:g} in the cluster" for k, (v, have) in short.items()
        )
        raise PlacementError(
            f"{n_workers} rollout workers cannot be placed ({said}): lower --workers or "
            "cluster.worker_cpus / cluster.worker_resources, or add nodes (a local Ray "
            "started by the trainer is sized for its workers)"
        )


def _cause(err: BaseException) -> str:
    """The root error of a Ray failure: the last line of its remote traceback."""
    lines = [line.strip() for line in str(err).splitlines() if line.strip()]
    return lines[-1] if lines else type(err).__name__


class Sampler:
    """A pool of ``RolloutWorker`` Ray actors, each owning ``envs_per_worker`` arenas."""

    def __init__(
        self,
        n_workers: int,
        *,
        env_kind: str,
        base_seed: int,
        worker_cpus: float,
        envs_per_worker: int = 1,
        groups: int = 1,
        servers_per_worker: int = 1,
        base_port: int = 0,
        env_options: Mapping[str, Any] | None = None,
        max_failures: int = 5,
        pipeline: int = 2,
        worker_resources: Mapping[str, float] | None = None,
        servers: ServerPool | None = None,
        start_timeout: float = START_TIMEOUT,
    ) -> None:
        self.env_kind, self.envs, self.groups = env_kind, envs_per_worker, groups
        self.servers_per_worker = servers_per_worker
        self.base_seed, self.base_port = base_seed, base_port
        self.env_options = dict(env_options or {})
        self.max_failures, self.pipeline = max_failures, pipeline
        self.servers = servers
        """Server actors the workers connect to (None: each worker's env finds its own)."""
        need = {"CPU": n_workers * worker_cpus}
        need.update({k: n_workers * v for k, v in (worker_resources or {}).items()})
        check_capacity(need, n_workers)
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
        self.opponents_ref: Any = None
        """Red's pool policies in the object store (None: no policy plays red)."""
        self.opponents_version = -1
        self._await_placement(start_timeout)

    def _spawn(self, i: int) -> Any:
        options = self.env_options
        port = self.base_port + i if self.base_port else None  # None: a private server
        if self.servers is not None:  # point worker i at its (live) server actor
            host, port = self.servers.endpoint(i)
            options = {**options, "host": host, "launch": False}
        return self.actor_cls.remote(
            i,
            self.env_kind,
            self.base_seed + i * self.envs,
            port,
            options,
            self.envs,
            self.groups,
            self.servers_per_worker if port is None else 1,
        )

    def _await_placement(self, timeout: float) -> None:
        """Wait until every worker answers, or close them all and say what is missing."""
        pings = {a.ping.remote(): i for i, a in enumerate(self.actors)}
        ready, pending = ray.wait(list(pings), num_returns=len(pings), timeout=timeout)
        try:
            ray.get(ready, timeout=timeout)
        except RayError as err:
            self.close()
            raise PlacementError(f"a rollout worker failed to start: {_cause(err)}") from err
        if pending:
            missing = sorted(pings[ref] for ref in pending)
            self.close()
            raise PlacementError(
                f"{len(missing)} of {len(pings)} rollout workers could not be placed or did not "
                f"start within {timeout:g} s (workers {missing[:10]}...); the cluster lacks the "
                "resources they ask for (worker_cpus, worker_resources): lower --workers or "
                f"cluster.worker_cpus, or add nodes. Ray sees {ray.available_resources()}"
            )

    def env_info(self) -> dict[str, Any]:
        """``get_env_info()`` of the first live worker's environment."""
        while True:
            i = self._live()[0]
            try:
                return ray.get(self.actors[i].env_info.remote(), timeout=START_TIMEOUT)
            except (RayError, GetTimeoutError) as err:
                self._fail(i, self.generation[i], err)

    def check_contexts(self, sets: Sequence[Mapping[str, Any]]) -> None:
        """Have the first live worker's arenas reset with each context set; the arena's
        ``InvalidContextError`` (naming the key and what is valid) comes back as is."""
        i = self._live()[0]
        try:
            ray.get(self.actors[i].check_contexts.remote(list(sets)), timeout=START_TIMEOUT)
        except RayError as err:
            cause = getattr(err, "cause", None)
            if isinstance(cause, InvalidContextError):
                raise cause from None
            raise

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
        """Put a new policy in the object store once; later chunks pass its reference."""
        self.weights_ref = ray.put(policy)
        self.version += 1

    def broadcast_opponents(self, policies: Mapping[str, Policy]) -> None:
        """Put red's pool policies (member id → policy) in the object store once; later
        chunks pass the reference (a worker loads a version once)."""
        self.opponents_ref = ray.put(dict(policies))
        self.opponents_version += 1

    def submit(
        self,
        requests: Sequence[Request],
        worker: int | None = None,
        opponents: tuple[Any, int] | None = None,
    ) -> None:
        """Queue one chunk of requests on a worker (the least loaded live one by default),
        with red's pool policies as last broadcast (or ``opponents``: a reference and its
        version)."""
        live = self._live()
        if worker is None or self.actors[worker] is None:
            load = {i: 0 for i in live}
            for task in self.in_flight.values():
                load[task.worker] = load.get(task.worker, 0) + 1
            worker = min(live, key=lambda i: load[i])
        actor = self.actors[worker]
        assert actor is not None
        opponents = opponents or (self.opponents_ref, self.opponents_version)
        ref = actor.run.remote(self.weights_ref, self.version, list(requests), *opponents)
        self.in_flight[ref] = _Task(worker, self.generation[worker], list(requests), opponents)

    def idle_slots(self) -> int:
        """Chunks that can be queued to keep ``pipeline`` per live worker in flight."""
        return self.pipeline * self.n_live - len(self.in_flight)

    def wait(self, timeout: float | None = None, kind: str = "train") -> list[Episode]:
        """The finished episodes of ``kind`` that landed, waiting at most ``timeout`` seconds
        (None: until at least one chunk lands) for one chunk to land."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            taken = [e for e in self.landed if e.info["kind"] == kind]
            if taken:
                self.landed = [e for e in self.landed if e.info["kind"] != kind]
                return taken
            if not any(r.kind == kind for t in self.in_flight.values() for r in t.requests):
                return []
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            ready, _ = ray.wait(list(self.in_flight), num_returns=1, timeout=left)
            if not ready:
                return []
            for ref in ready:
                self._harvest(ref)

    def _harvest(self, ref: Any) -> None:
        task = self.in_flight.pop(ref)
        try:
            episodes: list[Episode] = ray.get(ref)
        except RayError as err:
            self._fail(task.worker, task.generation, err)
            # the same chunk again, on a fresh actor
            self.submit(task.requests, task.worker, task.opponents)
            return
        self.failures[task.worker] = 0
        self.landed.extend(episodes)

    def _fail(self, i: int, generation: int, err: BaseException) -> None:
        """Restart worker ``i`` (once per generation), or give it up after too many failures."""
        if generation != self.generation[i] or self.actors[i] is None:
            return  # another request already reported this actor's death
        self.failures[i] += 1
        log.warning("rollout worker %d failed (%d in a row): %s", i, self.failures[i], _cause(err))
        ray.kill(self.actors[i], no_restart=True)
        self.generation[i] += 1
        if self.failures[i] >= self.max_failures:
            log.error("giving up rollout worker %d after %d failures", i, self.failures[i])
            self.actors[i] = None
            return
        time.sleep(min(0.25 * 2 ** (self.failures[i] - 1), 8.0))  # let a server come back
        self.actors[i] = self._spawn(i)
        self.restarts += 1

    def run(self, requests: Sequence[Request], timeout: float | None = None) -> list[Episode]:
        """Play all ``requests`` spread over the workers (consecutive shares) and wait for
        them, at most ``timeout`` seconds (None: no limit); episodes in seed order.

        Episodes of other kinds that land meanwhile are kept for the next :meth:`wait`.
        """
        if not requests:
            return []
        kind = requests[0].kind
        live = self._live()
        per = -(-len(requests) // len(live))
        for j, worker in enumerate(live):
            share = list(requests[j * per : (j + 1) * per])
            for start in range(0, len(share), self.envs * 4):  # chunks of a few episodes per arena
                self.submit(share[start : start + self.envs * 4], worker)
        deadline = None if timeout is None else time.monotonic() + timeout
        out: list[Episode] = []
        while len(out) < len(requests):
            left = None if deadline is None else deadline - time.monotonic()
            if left is not None and left <= 0:
                break
            got = self.wait(left, kind=kind)
            pending = any(r.kind == kind for t in self.in_flight.values() for r in t.requests)
            if not got and not pending:
                break
            out.extend(got)
        return sorted(out, key=lambda e: e.info["seed"])

    def close(self) -> None:
        """Close every worker's env, then stop the actors.

        Closing first releases a server that outlives the run (``neuronsmae-fleet``, a
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
