"""Where sampling runs on a Ray cluster: custom resources for workers, and where servers live.

Three ways to give each rollout worker ``i`` its server (``env="remote"``):

* ``servers="local"`` (the default): the worker's ``VecRM`` launches its own vector server
  (the server command with ``--arenas envs_per_worker``, unpaced) on the worker's node, bound to
  loopback, on a free port (or on ``base_port + i`` when ``base_port`` is set, where a
  running fleet is used), and stops it when the worker goes. Sampling traffic never leaves
  the node, and a worker restarted on another node brings its server along. Nothing in
  this module is needed for it.
* ``servers="actors"``: one :class:`ServerActor` per worker index, placed by Ray (on nodes
  with ``server_resources``), starts a vector server bound to its node's IP and reports
  host and port; the worker connects with ``VecRM(host=..., port=..., launch=False)``. For
  clusters where simulation and learning-side workers should sit on different machines.
* ``router="tcp/H:7447"``: the servers are run outside Ray (``neuronsmae-fleet --router
  --arenas envs_per_worker``) and every worker reaches server ``base_port + i`` through
  that Zenoh router.

``worker_resources`` (e.g. ``"sampler=1"``) makes each worker also require a custom resource,
so workers land only on nodes started with ``ray start --resources '{"sampler": N}'``, at
most N per node.

:func:`start_ray` starts the run's local Ray, sized so that every worker is placed however
few cores there are, or joins ``cluster.address``.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import socket
from collections.abc import Mapping
from typing import Any

import ray
from ray.exceptions import GetTimeoutError, RayError

from neuronsmae.client import answering_pid
from neuronsmae.protocol.launch import ServerCommand, ServerProcess, launch_private
from neuronsmae.trainers.run.config import ConfigError, TrainConfig, parse_resources

SERVER_STARTUP_S = 180.0
"""Seconds a server actor's server may take to answer (imports, JIT cache, arena build)."""
SERVER_CPUS = 0.5
"""CPUs Ray reserves per server actor (the server process does the simulation)."""


class ServerActor:
    """A server subprocess (the one-server command) on this actor's node, reachable from
    other nodes.

    A plain class: :class:`ServerPool` makes it a Ray actor. The server is a fresh
    interpreter (never a fork of a process with a Zenoh session) that watches this actor's
    pid, so it stops when the actor is killed.
    """

    def __init__(
        self, port: int, seed: int, arenas: int = 1, host: str = "", time_scale: float = 0.0
    ) -> None:
        self.host = host or ray.util.get_node_ip_address()
        self.port = port  # 0: a free port, picked at the first start
        self.seed, self.arenas, self.time_scale = seed, arenas, time_scale
        self.starts = 0
        self.server: ServerProcess | None = None
        self._start()

    def _start(self) -> None:
        """Launch (or relaunch, on the same port) the server the way ``RM`` launches one."""
        if self.server is not None:
            self.server.stop()
        self.starts += 1
        if self.port:
            self.server = ServerProcess(self._command(self.port))
            self.server.wait_ready(lambda: answering_pid(self.port, self.host), SERVER_STARTUP_S)
        else:
            self.server = launch_private(
                self._command,
                lambda port: answering_pid(port, self.host),
                self.host,
                timeout=SERVER_STARTUP_S,
            )
            self.port = self.server.port

    def _command(self, port: int) -> ServerCommand:
        return ServerCommand(
            port, self.seed, self.host, arenas=self.arenas, time_scale=self.time_scale
        )

    def address(self) -> tuple[str, int]:
        """Host and port of a live server (started again first if it has died)."""
        if self.server is None or self.server.proc.poll() is not None:
            self._start()
        return self.host, self.port

    def node_id(self) -> str:
        """The Ray node this actor (and so its server) runs on."""
        return ray.get_runtime_context().get_node_id()

    def close(self) -> None:
        """Stop the server; safe to call twice."""
        if self.server is not None:
            self.server.stop()


class ServerPool:
    """One :class:`ServerActor` per worker index, all started at once, reused by restarts."""

    def __init__(
        self,
        n: int,
        base_port: int,
        base_seed: int,
        resources: Mapping[str, float] | None = None,
        host: str = "",
        arenas: int = 1,
    ) -> None:
        self.base_port, self.base_seed, self.host = base_port, base_seed, host
        self.arenas = arenas
        self.actor_cls = ray.remote(
            num_cpus=SERVER_CPUS, resources=dict(resources or {}), max_restarts=0
        )(ServerActor)
        self.actors: dict[int, Any] = {i: self._spawn(i) for i in range(n)}
        refs = [a.address.remote() for a in self.actors.values()]
        self.addresses: dict[int, tuple[str, int]] = dict(
            enumerate(ray.get(refs, timeout=SERVER_STARTUP_S * 2))
        )

    def _spawn(self, i: int) -> Any:
        port = self.base_port + i if self.base_port else 0  # 0: a free port on its node
        seed = self.base_seed + i * self.arenas
        return self.actor_cls.remote(port, seed, self.arenas, self.host)

    def endpoint(self, i: int) -> tuple[str, int]:
        """Host and port of worker ``i``'s server (restarted, or placed anew, if it died)."""
        try:
            host, port = ray.get(self.actors[i].address.remote(), timeout=SERVER_STARTUP_S)
        except (RayError, GetTimeoutError):  # the actor itself is gone: place a new one
            ray.kill(self.actors[i], no_restart=True)
            self.actors[i] = self._spawn(i)
            host, port = ray.get(self.actors[i].address.remote(), timeout=SERVER_STARTUP_S)
        self.addresses[i] = (host, port)
        return host, port

    def close(self) -> None:
        """Stop every server and its actor."""
        refs = [a.close.remote() for a in self.actors.values()]
        with contextlib.suppress(RayError, GetTimeoutError):
            ray.get(refs, timeout=15)
        for actor in self.actors.values():
            ray.kill(actor, no_restart=True)
        self.actors.clear()


def sampler_placement(
    cfg: TrainConfig, n_workers: int, base_seed: int, env_options: Mapping[str, Any]
) -> dict[str, Any]:
    """The placement keyword arguments of :class:`~neuronsmae.trainers.run.sampler.Sampler`
    for ``cfg``, ``env_options`` (the arenas') among them with the router added when there
    is one (call after ``ray.init``: ``servers="actors"`` starts the servers here)."""
    out: dict[str, Any] = {
        "worker_resources": parse_resources(cfg.cluster.worker_resources),
        "env_options": dict(env_options),
    }
    if cfg.env == "remote" and cfg.cluster.router:
        out["env_options"]["router"] = cfg.cluster.router
    if cfg.env == "remote" and cfg.cluster.servers == "actors" and not cfg.cluster.router:
        out["servers"] = ServerPool(
            n_workers,
            cfg.cluster.base_port,
            base_seed,
            parse_resources(cfg.cluster.server_resources),
            arenas=cfg.envs_per_worker,
        )
    return out


def local_cpus(cfg: TrainConfig) -> int:
    """CPUs to tell a local Ray it has: the machine's, or as many as the workers (and their
    server actors) reserve plus one for the learner if that is more. Ray then places every
    worker however few cores there are (they share them, oversubscribed), instead of
    leaving some pending for ever."""
    need = cfg.n_workers() * cfg.cluster.worker_cpus
    if cfg.env == "remote" and cfg.cluster.servers == "actors":
        need += cfg.n_workers() * SERVER_CPUS
    cores = os.cpu_count() or 1
    if need > MAX_OVERSUBSCRIPTION * cores:
        raise ConfigError(
            f"workers={cfg.n_workers()} at worker_cpus={cfg.cluster.worker_cpus} reserve "
            f"{need:g} CPUs: a local Ray on this {cores}-core machine shares at most "
            f"{MAX_OVERSUBSCRIPTION * cores} among its workers; give fewer workers or a smaller "
            "worker_cpus, or join a Ray cluster (cluster.address) that has the CPUs"
        )
    return max(cores, math.ceil(need) + 1)


MAX_OVERSUBSCRIPTION = 32
"""A local Ray's CPUs may be at most this many times the machine's cores (25 workers of
half a CPU on 2 cores need 13): beyond it, workers would only thrash the cores."""


def start_ray(cfg: TrainConfig) -> None:
    """A local Ray sized by :func:`local_cpus`, or join ``cluster.address``; an address
    where no Ray cluster answers is a :class:`ConfigError` naming it."""
    address = cfg.cluster.address
    if address and address != "auto":
        check_reachable(address)
    try:
        ray.init(
            address=address or "local",  # never join a stray cluster by accident
            num_cpus=None if address else local_cpus(cfg),
            include_dashboard=False,
            logging_level=logging.WARNING,
            log_to_driver=False,
        )
    except ConnectionError as exc:
        raise ConfigError(
            f"cluster.address {address!r}: no Ray cluster answers there ({exc}); give the head "
            "node's host:port as `ray start --head` printed it, or leave it empty for a "
            "local Ray"
        ) from None


def check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Refuse a ``host:port`` (or ``ray://host:port``) where nothing accepts a connection
    within ``timeout_s``: ``ray.init`` itself keeps retrying such an address for minutes."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ConfigError(
            f"cluster.address must be 'auto', host:port or ray://host:port, got {address!r}"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise ConfigError(
            f"cluster.address {address!r}: nothing accepts connections there ({exc}); start "
            "the head with `ray start --head`, or leave the address empty for a local Ray"
        ) from None
