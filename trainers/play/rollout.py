"""Rollout workers: a plain class that owns a vector of arenas and plays whole episodes.

The class knows nothing about Ray; the sampler makes it an actor at the launch point with
``ray.remote(num_cpus=...)(RolloutWorker)``, and tests and evaluation use it directly.

A worker owns ``envs`` arenas behind one :class:`~neuronsmae.protocol.VecArenaAPI`: a
``VecArena`` in its own process (``inprocess``) or a ``VecRM`` of its own vector server
(``remote``). One :meth:`RolloutWorker.run` call plays a list of episode requests to their
ends, the arenas taking them in turn: every decision is one batched forward pass of the
agent network for all arenas' agents (each row with its episode's ε and masks), and one
vector step. A finished arena starts its next request in the following step (the vector's
next-step autoreset); an arena with nothing left to play is left idle until the others
finish. Only whole episodes are returned, and many environment steps are paid for by one
Ray call.

In a competitive arena (the agents are blue then red) the learner's policy drives blue and
red is the episode's opponent (``Request.opponent``): a pool member's policy, batched per
opponent on this worker (:class:`~neuronsmae.trainers.play.opponents.OpponentActors`), or the
arena's bot (``bot_team="red"``). Episodes hold blue's rows only.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol import EnvInfo, VecArenaAPI
from neuronsmae.protocol.interface import StepHandle, shares_of
from neuronsmae.trainers.core.acting import Policy
from neuronsmae.trainers.core.agent import epsilon_greedy
from neuronsmae.trainers.core.buffer import Episode
from neuronsmae.trainers.core.learner import AgentSpec
from neuronsmae.trainers.play.opponents import OpponentActors

DEFAULT_ENV_OPTIONS: Mapping[str, Any] = {
    "action_space": "abstract",
    "n_blue": 2,
    "n_red": 2,
    "mode": "cooperative",
}
"""Arena options of the cooperative 2 v 2 abstract-action task the paper trains on."""


def open_env(
    kind: str,
    seed: int,
    port: int | None,
    envs: int = 1,
    options: Mapping[str, Any] | None = None,
    servers: int = 1,
) -> VecArenaAPI:
    """Open ``envs`` arenas seeded ``seed, seed + 1, ...``: an in-process ``VecArena`` or a
    ``VecRM`` of a vector server (on ``port``; None launches ``servers`` private ones,
    unpaced, holding consecutive shares of the arenas).

    In-process arenas come through the client's ``env="inprocess"``, which imports the
    server package by name only then: a trainer that talks to remote servers needs only the
    client (trainers → client → protocol).
    """
    opts = {**DEFAULT_ENV_OPTIONS, **(options or {})}
    if kind == "inprocess":
        from neuronsmae.client import make_vec_arena

        return make_vec_arena("inprocess", seed, envs, **opts)
    if kind == "remote":
        from neuronsmae.client import VecRM

        return VecRM(seed, port=port, num_envs=envs, servers=servers if port is None else 1,
                     **opts)  # fmt: skip
    raise ValueError(f"unknown env kind {kind!r}; valid: inprocess, remote")


@dataclass(frozen=True)
class Request:
    """One episode to play."""

    seed: int
    """Reset seed of the episode."""
    epsilon: float
    """Exploration rate in [0, 1] (0: greedy evaluation)."""
    contexts: Mapping[str, Any] = field(default_factory=dict)
    """The episode's reset contexts (``level``, ``coef``, dynamics keys; docs/contexts.md)."""
    kind: str = "train"
    """``train`` (goes to the buffer) or ``eval`` (only counted)."""
    opponent: str = ""
    """Red's pool member (``bot:<level>``, ``ckpt:<path>``, ``self:<episodes>``; the
    contexts put a bot on red); "": the arena's own red (the ``level`` bot)."""


def blue_alive(info: Mapping[str, Any], n_agents: int) -> np.ndarray:
    """Which controlled robots are alive, from the referee's ``info['alive']``.

    ``alive`` lists every robot, controlled agents first (blue team), so the first
    ``n_agents`` entries are ours; a mapping keyed by robot name is read in its order.
    """
    alive = info["alive"]
    values = list(alive.values()) if isinstance(alive, Mapping) else list(alive)
    return np.asarray(values[:n_agents], dtype=bool)


class _Track:
    """The episode one arena is playing: its request and the rows gathered so far."""

    def __init__(
        self, order: int, request: Request, obs: np.ndarray, state: np.ndarray, avail: np.ndarray
    ) -> None:
        self.order, self.request = order, request
        self.start = time.perf_counter()
        self.obs, self.state, self.avail = [obs], [state], [avail]
        self.alive = [np.ones(obs.shape[0], dtype=bool)]
        self.actions: list[np.ndarray] = []
        self.rewards: list[float] = []

    def add(
        self,
        action: np.ndarray,
        reward: float,
        obs: np.ndarray,
        state: np.ndarray,
        avail: np.ndarray,
        alive: np.ndarray,
    ) -> None:
        self.actions.append(action)
        self.rewards.append(reward)
        self.obs.append(obs)
        self.state.append(state)
        self.avail.append(avail)
        self.alive.append(alive)

    def episode(self, info: Mapping[str, Any], worker: int) -> Episode:
        request = self.request
        return Episode(
            obs=np.stack(self.obs),
            state=np.stack(self.state),
            avail=np.stack(self.avail),
            alive=np.stack(self.alive),
            actions=np.stack(self.actions).astype(np.int64),
            rewards=np.asarray(self.rewards, np.float32),
            terminated=True,
            info={
                "winner": info.get("winner"),
                "seed": request.seed,
                "epsilon": request.epsilon,
                "contexts": dict(request.contexts),
                "kind": request.kind,
                "opponent": request.opponent,
                "worker": worker,
                "seconds": time.perf_counter() - self.start,
            },
        )


class _Arrays:
    """What the worker's arenas show now: blue's featurized observations and the masks its
    agents act with (the policy's :meth:`~.learner.AgentSpec.mask` of the arenas'), the
    global state, and red's raw observations and masks (competitive mode; else empty)."""

    def __init__(self, raw: np.ndarray, state: np.ndarray, avail: np.ndarray, n: int,
                 spec: AgentSpec, featurize: Any) -> None:  # fmt: skip
        self.obs, self.state = featurize(raw[:, :n]), state
        self.avail = spec.mask(avail[:, :n])
        self.red_obs, self.red_avail = raw[:, n:], avail[:, n:]

    def updated(self, rows: slice, raw: np.ndarray, env: VecArenaAPI, n: int,
                spec: AgentSpec, featurize: Any) -> _Arrays:  # fmt: skip
        """Fresh copies with ``rows`` taken from the step just received (the episodes keep
        views of the old arrays)."""
        new = object.__new__(_Arrays)
        state, avail = env.get_state(), env.get_avail_actions()
        for name in ("obs", "state", "avail", "red_obs", "red_avail"):
            setattr(new, name, getattr(self, name).copy())
        new.obs[rows] = featurize(raw[rows, :n])
        new.state[rows], new.avail[rows] = state[rows], spec.mask(avail[rows, :n])
        new.red_obs[rows], new.red_avail[rows] = raw[rows, n:], avail[rows, n:]
        return new


class _Slots:
    """A group of a worker's arenas that is stepped together, and what each arena is playing.

    Arenas ``lo .. hi - 1`` of the worker's vector. With two groups, one group's step runs
    on the server while the worker computes the other group's actions.
    """

    def __init__(self, worker: RolloutWorker, lo: int, hi: int) -> None:
        self.worker, self.lo, self.hi = worker, lo, hi
        k = hi - lo
        self.tracks: list[_Track | None] = [None] * k
        self.following: list[tuple[int, Request] | None] = [None] * k
        """The request an arena whose episode just ended plays next (reset by the next step)."""
        self.hidden = worker.agent.initial_hidden(k * worker.n_agents)
        self.last = torch.full((k, worker.n_agents), -1, dtype=torch.int64)
        self.actions = self.last

    @property
    def busy(self) -> bool:
        return any(t is not None for t in self.tracks)

    def _begin(self, i: int, entry: tuple[int, Request], now: _Arrays) -> None:
        """Arena ``lo + i`` starts the episode ``entry``: its track, and red's opponent."""
        j = self.lo + i
        self.tracks[i] = _Track(*entry, now.obs[j], now.state[j], now.avail[j])
        if self.worker.opponents is not None:
            self.worker.opponents.begin(j, entry[1].opponent)

    def start(self, entries: list[tuple[int, Request] | None], now: _Arrays) -> None:
        """The first episode of each arena (None: the arena has nothing to play)."""
        for i, entry in enumerate(entries):
            if entry is not None:
                self._begin(i, entry, now)

    def send(self, spec: AgentSpec, now: _Arrays) -> StepHandle:
        """Choose every arena's actions (one batched forward for blue, one per opponent for
        red) and start the group's step."""
        w, n, lo, hi = self.worker, self.worker.n_agents, self.lo, self.hi
        eps = torch.tensor([0.0 if t is None else t.request.epsilon for t in self.tracks])
        inputs = spec.inputs(torch.from_numpy(now.obs[lo:hi]), self.last)  # [k, n, D]
        q, self.hidden = w.agent(inputs.reshape((hi - lo) * n, 1, -1), self.hidden)
        self.actions = epsilon_greedy(
            q[:, 0], torch.from_numpy(now.avail[lo:hi]).reshape((hi - lo) * n, -1),
            eps.repeat_interleave(n), w.generator,
        ).reshape(hi - lo, n)  # fmt: skip
        rows = np.zeros((w.envs, n + w.n_red), dtype=np.int64)
        rows[lo:hi, :n] = self.actions.numpy()
        if w.opponents is not None:
            rows[lo:hi, n:] = w.opponents.act(lo, hi, now.red_obs[lo:hi], now.red_avail[lo:hi])
        seeds: list[int | None] = [None] * w.envs
        contexts: list[dict[str, Any] | None] = [None] * w.envs
        active = np.zeros(w.envs, dtype=bool)
        for i, (track, nxt) in enumerate(zip(self.tracks, self.following, strict=True)):
            active[lo + i] = track is not None
            if nxt is not None:  # this arena resets in this step (next-step autoreset)
                seeds[lo + i], contexts[lo + i] = nxt[1].seed, dict(nxt[1].contexts)
        return w.env.step_async(rows, seeds=seeds, contexts=contexts, active=active)

    def receive(
        self,
        step: tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]],
        now: _Arrays,
        queue: list[tuple[int, Request]],
        out: list[Episode | None],
    ) -> None:
        """Record the step's transitions (``now``: the arenas after it); hand finished
        episodes to ``out`` and the next requests to their arenas."""
        w, n = self.worker, self.worker.n_agents
        _, rewards, dones, infos = step
        actions = self.actions
        for i, track in enumerate(self.tracks):
            if track is None:
                continue
            j, nxt = self.lo + i, self.following[i]
            if nxt is not None:  # reset by this step: the new episode's first rows
                self._begin(i, nxt, now)
                self.following[i] = None
                self.hidden[:, i * n : (i + 1) * n] = 0.0
                actions[i] = -1
                continue
            track.add(actions[i].numpy().copy(), float(np.mean(rewards[j, :n])), now.obs[j],
                      now.state[j], now.avail[j], blue_alive(infos[j], n))  # fmt: skip
            if dones[j]:
                out[track.order] = track.episode(infos[j], w.index)
                if queue:  # the arena plays the next request, reset by the next step
                    self.following[i] = queue.pop(0)
                else:
                    self.tracks[i] = None
        self.last = actions


class RolloutWorker:
    """Owns ``envs`` arenas and the acting copy of the shared agent network.

    ``servers`` (``env_kind`` remote, ``port`` None): private vector servers holding
    consecutive shares of the arenas; every step goes to all of them at once, so they step
    their shares side by side on the node's cores while the worker waits for the slowest.
    ``groups`` splits the arenas into groups (the same shares) stepped in turn: the worker
    chooses one group's actions while the other's arenas step; a step whose server holds
    none of the group's arenas is not sent. In process there is nothing to overlap, and one
    group (one forward pass for all arenas) is best.
    """

    def __init__(
        self,
        index: int,
        env_kind: str,
        env_seed: int,
        port: int | None,
        env_options: Mapping[str, Any] | None = None,
        envs: int = 1,
        groups: int = 1,
        servers: int = 1,
    ) -> None:
        torch.set_num_threads(1)  # many workers share few cores; one thread each is fastest
        self.index = index
        self.env = open_env(env_kind, env_seed, port, envs, env_options, servers)
        self.envs = envs
        self.groups = max(1, min(groups, envs))
        info = EnvInfo.from_dict(self.env.get_env_info())
        # Blue's agents are the learner's; a competitive arena's other agents are red's.
        self.n_agents, self.n_actions = info.team_size, info.n_actions
        self.n_red = info.n_agents - info.team_size
        self.opponents = OpponentActors(envs, self.n_red) if self.n_red else None
        self.spec: AgentSpec | None = None
        self.agent: Any = None
        self.version = -1
        self.generator = torch.Generator().manual_seed(env_seed)

    def env_info(self) -> dict[str, Any]:
        """The environment's ``get_env_info()`` (the learner sizes its networks from it)."""
        return self.env.get_env_info()

    def set_policy(self, policy: Policy, version: int) -> None:
        """Load the learner's policy unless this version is already loaded."""
        if version == self.version:
            return
        if policy.spec != self.spec:
            self.spec, self.agent = policy.spec, policy.spec.build().eval()
        self.agent.load_state_dict({k: torch.as_tensor(v) for k, v in policy.weights.items()})
        self.version = version

    def run_episode(
        self, policy: Policy, version: int, epsilon: float, seed: int, contexts: Mapping[str, Any]
    ) -> Episode:
        """Play one whole episode with ε-greedy actions and return it (see :meth:`run`)."""
        return self.run(policy, version, [Request(seed, epsilon, dict(contexts))])[0]

    def set_opponents(self, opponents: Mapping[str, Policy] | None, version: int) -> None:
        """Load red's pool policies (member id → policy) unless this version is loaded."""
        if opponents is None:
            return
        if self.opponents is None:
            raise ValueError(
                "opponent policies need a competitive arena (mode='competitive'), whose "
                "agents include red's"
            )
        self.opponents.load(opponents, version)

    @torch.no_grad()
    def run(
        self,
        policy: Policy,
        version: int,
        requests: Sequence[Request],
        opponents: Mapping[str, Policy] | None = None,
        opponents_version: int = -1,
    ) -> list[Episode]:
        """Play every request to its end, ``envs`` at a time; the episodes in request order.

        ``opponents``: the policies of red's pool members the requests name (competitive
        arenas). Nothing is returned unless every episode reached ``done``: if the
        environment fails the exception propagates and the partial episodes are lost.
        """
        if not requests:
            return []
        self.set_policy(policy, version)
        self.set_opponents(opponents, opponents_version)
        spec, env, k, n = policy.spec, self.env, self.envs, self.n_agents
        featurize = spec.featurizer()
        queue = list(enumerate(requests))
        first = [queue.pop(0) if queue else None for _ in range(k)]
        raw = env.reset(
            [None if f is None else dict(f[1].contexts) for f in first],
            [None if f is None else f[1].seed for f in first],
        )
        now = _Arrays(raw, env.get_state(), env.get_avail_actions(), n, spec, featurize)
        bounds = np.cumsum([0, *shares_of(k, self.groups)])  # as the servers' shares
        groups = [_Slots(self, lo, hi) for lo, hi in itertools.pairwise(bounds)]
        for g in groups:
            g.start(first[g.lo : g.hi], now)
        out: list[Episode | None] = [None] * len(requests)
        pending = [g.send(spec, now) if g.busy else None for g in groups]
        while any(p is not None for p in pending):
            for i, g in enumerate(groups):
                handle = pending[i]
                if handle is None:
                    continue
                step = handle.result()
                # Only this group's rows changed.
                now = now.updated(slice(g.lo, g.hi), step[0], env, n, spec, featurize)
                g.receive(step, now, queue, out)
                pending[i] = g.send(spec, now) if g.busy else None
        return [episode for episode in out if episode is not None]

    def check_contexts(self, sets: Sequence[Mapping[str, Any]]) -> None:
        """Reset the arenas with each context set in turn (the arena raises
        ``InvalidContextError`` for a key or value it refuses); the next :meth:`run` resets
        them again."""
        for contexts in sets:
            self.env.reset(dict(contexts))

    def ping(self) -> int:
        """Answer once ``__init__`` has finished (the env is open)."""
        return self.index

    def close(self) -> None:
        """Close the environment."""
        self.env.close()
