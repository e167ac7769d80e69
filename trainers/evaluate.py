"""Greedy evaluation: outcome statistics, a policy loaded from a checkpoint, and a match.

:func:`evaluate_checkpoint` plays a checkpoint's agents greedily (ε = 0, available actions
only) against a bot on seeds ``seed, seed+1, ...`` and returns the win rate.
:class:`GreedyPolicy` is the same agent as a step-by-step controller for other callers; the
match and league commands play checkpoints batched through :mod:`.policies`.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np
import torch

from neuronsmae.protocol.errors import InvalidContextError
from neuronsmae.protocol.levels import level_error, level_from_arg, level_value
from neuronsmae.trainers.agent import masked_greedy
from neuronsmae.trainers.buffer import Episode
from neuronsmae.trainers.checkpoint import checkpoint_path, load_checkpoint, policy_weights
from neuronsmae.trainers.learner import AgentSpec
from neuronsmae.trainers.rollout import Policy, Request, RolloutWorker
from neuronsmae.trainers.task import trained_options


def summarize(episodes: Iterable[Episode]) -> dict[str, float]:
    """Win, draw and loss rates and the mean team return of finished episodes."""
    eps = list(episodes)
    if not eps:
        raise ValueError("no episodes to summarise")
    winners = [e.info.get("winner") for e in eps]
    n = len(eps)
    return {
        "win_rate": sum(w == "blue" for w in winners) / n,
        "draw_rate": sum(w == "draw" for w in winners) / n,
        "loss_rate": sum(w == "red" for w in winners) / n,
        "mean_return": float(np.mean([e.total_reward for e in eps])),
        "mean_length": float(np.mean([e.length for e in eps])),
        "eval_episodes": n,
    }


def load_policy(path: str | os.PathLike[str]) -> Policy:
    """The acting part of a checkpoint (file or run directory): architecture and weights."""
    payload = load_checkpoint(path)
    spec = AgentSpec(**payload["agent_spec"])
    return Policy(spec, policy_weights(payload["learner"]))


class GreedyPolicy:
    """A checkpoint's agents as a controller: call :meth:`reset`, then :meth:`act` each step."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        policy = load_policy(path)
        self.spec = policy.spec
        self.featurize = policy.spec.featurizer()
        self.agent = policy.spec.build().eval()
        self.agent.load_state_dict({k: torch.as_tensor(v) for k, v in policy.weights.items()})
        self.hidden: torch.Tensor | None = None
        self.last: torch.Tensor | None = None

    def reset(self) -> None:
        """Forget the recurrent state at the start of an episode."""
        self.hidden, self.last = None, None

    @torch.no_grad()
    def q_values(self, obs: Sequence[np.ndarray]) -> torch.Tensor:
        """Q-values ``[n_agents, n_actions]`` for this decision; advances the recurrent state.

        Follow it with :meth:`chose` (``act`` does both), so the next decision's input holds
        the actions actually taken.
        """
        x = torch.as_tensor(self.featurize(np.asarray(obs, np.float32)))
        n = x.shape[0]
        if self.hidden is None or self.last is None:
            self.hidden = self.agent.initial_hidden(n)
            self.last = torch.full((n,), -1, dtype=torch.int64)
        inputs = self.spec.inputs(x, self.last)
        q, self.hidden = self.agent(inputs.unsqueeze(1), self.hidden)
        return q[:, 0]

    def chose(self, actions: torch.Tensor) -> None:
        """Record the actions taken (``[n_agents]``, int64): the next input's last actions."""
        self.last = actions

    def act(self, obs: Sequence[np.ndarray], avail: Sequence[np.ndarray]) -> list[int]:
        """Greedy available action of every agent, given their observations and masks."""
        return act_greedily(self, obs, avail)[0]


class QPolicy(Protocol):
    """A greedy controller as :func:`act_greedily` drives it: ``reset`` per episode, then per
    decision Q-values (which advance the recurrent state) and the actions taken told back."""

    def reset(self) -> None: ...

    def q_values(self, obs: Sequence[np.ndarray]) -> torch.Tensor: ...

    def chose(self, actions: torch.Tensor) -> None: ...


def act_greedily(
    policy: QPolicy, obs: Sequence[np.ndarray], avail: Sequence[np.ndarray]
) -> tuple[list[int], float]:
    """Each agent's greedy available action, and the team's value of them: the sum over
    agents of the chosen Q-values (VDN's team value; what the agents expect the rest of the
    episode to bring)."""
    allowed = torch.as_tensor(np.asarray(avail)) > 0
    q = policy.q_values(obs)
    chosen = masked_greedy(q, allowed)
    policy.chose(chosen)
    value = float(q.gather(-1, chosen.unsqueeze(-1)).sum())
    return [int(a) for a in chosen], value


def evaluate_checkpoint(
    path: str | os.PathLike[str],
    level: str | int,
    episodes: int,
    seed: int,
    *,
    contexts: Mapping[str, Any] | None = None,
    env: str = "inprocess",
    port: int | None = None,
    envs: int = 8,
) -> dict[str, Any]:
    """Play a checkpoint greedily against the ``level`` bot for ``episodes`` episodes.

    ``level`` is a bot name or a released level, as a number or as a command line gives it
    ("0", "1"); anything else raises ``InvalidContextError`` listing the valid levels.

    Episode ``k`` is reset with seed ``seed + k``, so two checkpoints evaluated with the same
    arguments meet exactly the same starts. ``contexts`` adds reset contexts (e.g.
    ``{"coef": 1.5}``). ``envs`` arenas play at once (``env="remote"``: on a server at
    ``port``, or a private one when None), with the options the run trained with. Returns
    the rates of :func:`summarize` plus
    ``level``, ``seed``, ``checkpoint``, the run's ``alg`` and its training
    ``episodes_trained``.
    """
    chosen = level_value(level_from_arg(level) if isinstance(level, str) else level)
    if chosen is None:
        raise InvalidContextError(level_error("level", level))
    if episodes < 1:
        raise ValueError(f"episodes must be ≥ 1, got {episodes}")
    level = chosen
    payload = load_checkpoint(path)
    policy = load_policy(path)
    options = {**trained_options(payload["config"]), "mode": "cooperative"}
    worker = RolloutWorker(0, env, seed, port, options, envs=min(envs, episodes))
    ctx = {**(contexts or {}), "level": level}
    try:
        played = worker.run(
            policy, 0, [Request(seed + k, 0.0, ctx, "eval") for k in range(episodes)]
        )
    finally:
        worker.close()
    return {
        **summarize(played),
        "level": level,
        "seed": seed,
        "checkpoint": str(checkpoint_path(path)),
        "alg": payload["config"]["alg"],
        "episodes_trained": payload["counters"]["episodes"],
    }


class MatchPolicy(GreedyPolicy):
    """A checkpoint of the default task as a one-arena controller with its arena options
    (``bench/outcomes.py``); the match command uses :mod:`.policies` instead."""

    options: dict[str, Any] = {"action_space": "abstract"}  # noqa: RUF012
    """Arena options of the default task (abstract 2 v 2, cooperative)."""

    def act(
        self, obs: Sequence[np.ndarray], avail: Sequence[np.ndarray], state: Any = None
    ) -> list[int]:
        """Greedy actions; the global state is not needed by decentralised agents."""
        return super().act(obs, avail)
