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
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol import EnvInfo, VecArenaAPI
from neuronsmae.trainers.agent import epsilon_greedy
from neuronsmae.trainers.buffer import Episode
from neuronsmae.trainers.learner import AgentSpec

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
) -> VecArenaAPI:
    """Open ``envs`` arenas seeded ``seed, seed + 1, ...``: an in-process ``VecArena`` or a
    ``VecRM`` of a vector server (on ``port``; None launches a private one, unpaced).

    The server package is imported only for ``inprocess``, so a trainer that talks to remote
    servers needs only the client (trainers → client → protocol).
    """
    opts = {**DEFAULT_ENV_OPTIONS, **(options or {})}
    if kind == "inprocess":
        from neuronsmae.server import VecArena

        return VecArena(seed, envs, **opts)
    if kind == "remote":
        from neuronsmae.client import VecRM

        return VecRM(seed, port=port, num_envs=envs, **opts)
    raise ValueError(f"unknown env kind {kind!r}; valid: inprocess, remote")


@dataclass(frozen=True)
class Policy:
    """What a worker needs to act: the agent architecture and its weights.

    The architecture travels with the weights so a worker can be started before the
    learner knows the environment's sizes (it learns them from the first worker).
    """

    spec: AgentSpec
    """Agent network architecture and input options."""
    weights: dict[str, np.ndarray]
    """The agent's ``state_dict`` as NumPy arrays."""


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
                "worker": worker,
                "seconds": time.perf_counter() - self.start,
            },
        )


class RolloutWorker:
    """Owns ``envs`` arenas and the acting copy of the shared agent network."""

    def __init__(
        self,
        index: int,
        env_kind: str,
        env_seed: int,
        port: int | None,
        env_options: Mapping[str, Any] | None = None,
        envs: int = 1,
    ) -> None:
        torch.set_num_threads(1)  # many workers share few cores; one thread each is fastest
        self.index = index
        self.env = open_env(env_kind, env_seed, port, envs, env_options)
        self.envs = envs
        info = EnvInfo.from_dict(self.env.get_env_info())
        self.n_agents, self.n_actions = info.n_agents, info.n_actions
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

    @torch.no_grad()
    def run(self, policy: Policy, version: int, requests: Sequence[Request]) -> list[Episode]:
        """Play every request to its end, ``envs`` at a time; the episodes in request order.

        Nothing is returned unless every episode reached ``done``: if the environment fails
        the exception propagates and the partial episodes are simply lost.
        """
        if not requests:
            return []
        self.set_policy(policy, version)
        spec, agent, env = policy.spec, self.agent, self.env
        featurize = spec.featurizer()
        k, n = self.envs, self.n_agents
        queue = list(enumerate(requests))
        starting = [queue.pop(0) if queue else None for _ in range(k)]
        obs = featurize(env.reset(
            [None if s is None else dict(s[1].contexts) for s in starting],
            [None if s is None else s[1].seed for s in starting],
        ))  # fmt: skip
        state, avail = env.get_state(), env.get_avail_actions()
        tracks: list[_Track | None] = [
            None if s is None else _Track(s[0], s[1], obs[i], state[i], avail[i])
            for i, s in enumerate(starting)
        ]
        following: list[tuple[int, Request] | None] = [None] * k
        """The request an arena whose episode just ended plays next (reset in the next step)."""
        hidden = agent.initial_hidden(k * n)
        last = torch.full((k, n), -1, dtype=torch.int64)
        out: list[Episode | None] = [None] * len(requests)
        while any(t is not None for t in tracks):
            eps = torch.tensor([0.0 if t is None else t.request.epsilon for t in tracks])
            inputs = spec.inputs(torch.from_numpy(obs), last)  # [k, n, D]
            q, hidden = agent(inputs.reshape(k * n, 1, -1), hidden)
            actions = epsilon_greedy(
                q[:, 0], torch.from_numpy(avail).reshape(k * n, -1),
                eps.repeat_interleave(n), self.generator,
            ).reshape(k, n)  # fmt: skip
            seeds = [None if f is None else f[1].seed for f in following]
            contexts = [None if f is None else dict(f[1].contexts) for f in following]
            active = np.array([t is not None for t in tracks])
            raw, rewards, dones, infos = env.step(
                actions.numpy(), seeds=seeds, contexts=contexts, active=active
            )
            obs, state, avail = featurize(raw), env.get_state(), env.get_avail_actions()
            for i, track in enumerate(tracks):
                if track is None:
                    continue
                nxt = following[i]
                if nxt is not None:  # reset by this step (next-step autoreset): first rows
                    tracks[i] = _Track(*nxt, obs[i], state[i], avail[i])
                    following[i] = None
                    hidden[:, i * n : (i + 1) * n] = 0.0
                    actions[i] = -1
                    continue
                alive = blue_alive(infos[i], n)
                track.add(actions[i].numpy().copy(), float(np.mean(rewards[i])), obs[i], state[i],
                          avail[i], alive)  # fmt: skip
                if dones[i]:
                    out[track.order] = track.episode(infos[i], self.index)
                    if queue:  # the arena plays the next request, reset by the next step
                        following[i] = queue.pop(0)
                    else:
                        tracks[i] = None
            last = actions
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
