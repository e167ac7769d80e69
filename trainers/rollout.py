"""Rollout workers: a plain class that owns one environment and plays whole episodes.

The class knows nothing about Ray; the sampler makes it an actor at the launch point with
``ray.remote(num_cpus=...)(RolloutWorker)``, and tests and evaluation use it directly. One
call plays one whole episode (50 decisions), never one step, so the per-call overhead of
Ray is paid once per episode. The environment is opened in ``__init__`` so a worker that
cannot reach its env fails at once, where the sampler can restart it.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from neuronsmae.protocol import ArenaAPI, EnvInfo
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


def open_env(kind: str, seed: int, port: int, options: Mapping[str, Any] | None = None) -> ArenaAPI:
    """Open one environment: an in-process ``Arena`` or a ``RM`` client of a server.

    The server package is imported only for ``inprocess``, so a trainer that talks to remote
    servers needs only the client (trainers → client → protocol).
    """
    opts = {**DEFAULT_ENV_OPTIONS, **(options or {})}
    if kind == "inprocess":
        try:
            from neuronsmae.server import Arena
        except ImportError:  # the package may not re-export it; the module always has it
            from neuronsmae.server.arena import Arena

        return Arena(seed=seed, **opts)
    if kind == "remote":
        from neuronsmae.client import RM

        return RM(seed=seed, port=port, **opts)
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


def blue_alive(info: Mapping[str, Any], n_agents: int) -> np.ndarray:
    """Which controlled robots are alive, from the referee's ``info['alive']``.

    ``alive`` lists every robot, controlled agents first (blue team), so the first
    ``n_agents`` entries are ours; a mapping keyed by robot name is read in its order.
    """
    alive = info["alive"]
    values = list(alive.values()) if isinstance(alive, Mapping) else list(alive)
    return np.asarray(values[:n_agents], dtype=bool)


class RolloutWorker:
    """Owns one environment and the acting copy of the shared agent network."""

    def __init__(
        self,
        index: int,
        env_kind: str,
        env_seed: int,
        port: int,
        env_options: Mapping[str, Any] | None = None,
    ) -> None:
        torch.set_num_threads(1)  # many workers share few cores; one thread each is fastest
        self.index = index
        self.env = open_env(env_kind, env_seed, port, env_options)
        info = EnvInfo.from_dict(self.env.get_env_info())
        self.n_agents, self.episode_limit = info.n_agents, info.episode_limit
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

    @torch.no_grad()
    def run_episode(
        self, policy: Policy, version: int, epsilon: float, seed: int, contexts: Mapping[str, Any]
    ) -> Episode:
        """Play one whole episode with ε-greedy actions and return it.

        Nothing is returned unless the episode reached ``done``: if the environment fails
        mid-episode the exception propagates and the partial episode is simply lost.
        """
        self.set_policy(policy, version)
        spec = policy.spec
        featurize = spec.featurizer()
        start = time.perf_counter()
        env, n = self.env, self.n_agents
        obs = [featurize(np.asarray(env.reset(contexts=dict(contexts), seed=seed), np.float32))]
        states = [np.asarray(env.get_state(), np.float32)]
        avails = [np.asarray(env.get_avail_actions(), np.int8)]
        alive = [np.ones(n, dtype=bool)]
        actions: list[np.ndarray] = []
        rewards: list[float] = []
        hidden = self.agent.initial_hidden(n)
        last = torch.full((n,), -1, dtype=torch.int64)
        done, info = False, {}
        for _ in range(self.episode_limit):
            inputs = spec.inputs(torch.from_numpy(obs[-1]), last)
            q, hidden = self.agent(inputs.unsqueeze(1), hidden)
            act = epsilon_greedy(q[:, 0], torch.from_numpy(avails[-1]), epsilon, self.generator)
            next_obs, reward, done, info = env.step([int(a) for a in act])
            actions.append(act.numpy())
            rewards.append(float(np.mean(reward)))
            obs.append(featurize(np.asarray(next_obs, np.float32)))
            states.append(np.asarray(env.get_state(), np.float32))
            avails.append(np.asarray(env.get_avail_actions(), np.int8))
            alive.append(blue_alive(info, n))
            last = act
            if done:
                break
        return Episode(
            obs=np.stack(obs),
            state=np.stack(states),
            avail=np.stack(avails),
            alive=np.stack(alive),
            actions=np.stack(actions).astype(np.int64),
            rewards=np.asarray(rewards, np.float32),
            terminated=bool(done),
            info={
                "winner": info.get("winner"),
                "seed": seed,
                "epsilon": epsilon,
                "worker": self.index,
                "seconds": time.perf_counter() - start,
            },
        )

    def ping(self) -> int:
        """Answer once ``__init__`` has finished (the env is open)."""
        return self.index

    def close(self) -> None:
        """Close the environment."""
        self.env.close()
