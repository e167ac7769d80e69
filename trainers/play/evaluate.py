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

from neuronsmae.protocol.errors import InvalidContextError, InvalidOptionError, NeuronsMAEError
from neuronsmae.protocol.interface import check_series_seed, count_option, plain_contexts
from neuronsmae.protocol.levels import level_error, level_from_arg, level_value
from neuronsmae.protocol.messages import MAX_ARENAS
from neuronsmae.trainers.core.acting import Policy, acting_shape
from neuronsmae.trainers.core.agent import action_mask, masked_greedy, observations
from neuronsmae.trainers.core.buffer import Episode
from neuronsmae.trainers.core.checkpoint import (
    CheckpointError,
    acting_parts,
    checkpoint_path,
    load_checkpoint,
)
from neuronsmae.trainers.play.rollout import Request, RolloutWorker
from neuronsmae.trainers.play.task import trained_options

ENV_KINDS = ("inprocess", "remote")
MASK_AXES = ("n_agents", "n_actions")


RELEASED_WIN_REWARD = 13.0
"""The released code's win rule: an episode is won when agent 0's reward at the last
decision is above this (common/rollout.py; a win pays +20, a loss −20)."""


def summarize(episodes: Iterable[Episode]) -> dict[str, float]:
    """Win, draw and loss rates by the referee, the win rate by the released code's rule
    (:data:`RELEASED_WIN_REWARD`), and the mean team return of finished episodes."""
    eps = list(episodes)
    if not eps:
        raise ValueError("no episodes to summarise")
    winners = [e.info.get("winner") for e in eps]
    n = len(eps)
    # Every robot of a team gets the same reward, so the team's is agent 0's.
    released = sum(float(e.rewards[-1]) > RELEASED_WIN_REWARD for e in eps)
    return {
        "win_rate": sum(w == "blue" for w in winners) / n,
        "released_win_rate": released / n,
        "draw_rate": sum(w == "draw" for w in winners) / n,
        "loss_rate": sum(w == "red" for w in winners) / n,
        "mean_return": float(np.mean([e.total_reward for e in eps])),
        "mean_length": float(np.mean([e.length for e in eps])),
        "eval_episodes": n,
    }


def load_policy(path: str | os.PathLike[str]) -> Policy:
    """The acting part of a checkpoint (file or run directory): architecture and weights.

    :class:`CheckpointError` naming the file when it is no checkpoint, or its spec or
    weights are missing, mistyped or do not fit each other."""
    spec, weights, _ = acting_parts(load_checkpoint(path), path)
    return Policy(spec, weights)


def _checked(payload: dict[str, Any], path: str | os.PathLike[str], what: str, read: Any) -> Any:
    """``read(payload)``, or :class:`CheckpointError` naming the file and ``what`` it could
    not give (a config or counters missing or of another shape)."""
    try:
        return read(payload)
    except (NeuronsMAEError, ValueError, TypeError, KeyError, AttributeError) as exc:
        raise CheckpointError(
            f"{checkpoint_path(path)}: its {what} cannot be read ({type(exc).__name__}: {exc})"
        ) from exc


def checkpoint_options(payload: dict[str, Any], path: str | os.PathLike[str]) -> dict[str, Any]:
    """The arena options a loaded checkpoint's run trained with (without the mode);
    :class:`CheckpointError` naming the file when its ``config`` cannot give them."""
    return _checked(payload, path, "config's arena options",
                    lambda p: trained_options(p["config"]))  # fmt: skip


def run_facts(payload: dict[str, Any], path: str | os.PathLike[str]) -> dict[str, Any]:
    """A loaded checkpoint's arena options (``options``), algorithm (``alg``) and training
    episodes (``episodes_trained``); :class:`CheckpointError` naming the file otherwise."""
    return {
        "options": checkpoint_options(payload, path),
        "alg": _checked(payload, path, "config's alg", lambda p: str(p["config"]["alg"])),
        "episodes_trained": _checked(payload, path, "counters' episodes",
                                     lambda p: int(p["counters"]["episodes"])),
    }  # fmt: skip


class GreedyPolicy:
    """A checkpoint's agents as a controller: call :meth:`reset`, then :meth:`act` each step.

    Observations ``[n_agents, obs_dim]`` and masks ``[n_agents, n_actions]`` (1 or True:
    available) of the team the checkpoint was trained for; anything else, or a mask that
    leaves an agent no action, is a :class:`~neuronsmae.trainers.core.agent.PolicyInputError`
    that leaves the recurrent state as it was."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        spec, weights, n_agents = acting_parts(load_checkpoint(path), path)
        self.spec = spec
        self.n_agents, self.obs_dim = acting_shape(spec, n_agents)
        self.mask_shape = (self.n_agents, spec.n_actions)
        """What :meth:`act` takes as masks: ``(n_agents, n_actions)``."""
        self.featurize = spec.featurizer()
        self.agent = spec.build().eval()
        self.agent.load_state_dict({k: torch.as_tensor(v) for k, v in weights.items()})
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
        n, d = self.n_agents, self.obs_dim
        raw = observations(obs, (n, d), ("n_agents", "obs_dim"))
        x = torch.as_tensor(self.featurize(raw))
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
    episode to bring).

    The masks are checked first, against the policy's ``mask_shape`` when it has one (a
    :class:`GreedyPolicy` does), else against the Q-values' shape: 0/1 values, and at
    least one available action per agent (:class:`~neuronsmae.trainers.core.agent.PolicyInputError`
    naming the agent otherwise)."""
    shape = getattr(policy, "mask_shape", None)
    if shape is not None:  # checked before the recurrent state advances
        allowed = action_mask(avail, tuple(shape), MASK_AXES)
    q = policy.q_values(obs)
    if shape is None:
        allowed = action_mask(avail, tuple(q.shape), MASK_AXES)
    spec = getattr(policy, "spec", None)
    if spec is not None:  # a policy trained without masks acts without them
        allowed = spec.mask(allowed)
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
    ``{"coef": 1.5}``; not ``level``, which is its own argument). ``envs`` arenas play at
    once (``env="remote"``: on a server at ``port``, or a private one when None), with the
    options the run trained with. Returns
    the rates of :func:`summarize` plus
    ``level``, ``seed``, ``checkpoint``, the run's ``alg`` and its training
    ``episodes_trained``.

    Every argument is checked before anything loads or plays: ``episodes`` an integer ≥ 1,
    ``seed`` an integer with ``seed + episodes - 1`` ≤ 2⁶³ − 1, ``envs`` in [1, 64]
    (Python or NumPy integers), ``contexts`` a mapping, ``env`` one of ``inprocess`` and
    ``remote``, and ``port`` only with ``remote``; errors name the argument and its range.
    """
    chosen = level_value(level_from_arg(level) if isinstance(level, str) else level)
    if chosen is None:
        raise InvalidContextError(level_error("level", level))
    episodes = count_option("episodes", episodes, 1)
    seed = check_series_seed(seed, episodes)
    envs = count_option("envs", envs, 1, MAX_ARENAS)
    ctx = plain_contexts(contexts) or {}
    if "level" in ctx:  # the bot is an argument of its own: one of the two would be ignored
        raise InvalidContextError(
            f"contexts: level={ctx['level']!r:.40} beside level={level!r:.40}; give the bot "
            "as the level argument only"
        )
    ctx = {**ctx, "level": chosen}
    if env not in ENV_KINDS:
        raise InvalidOptionError(f"env must be one of {list(ENV_KINDS)}, got {env!r:.60}")
    if port is not None:
        if env != "remote":
            raise InvalidOptionError(
                f"port={port!r:.20} needs env='remote' (a server to play on); "
                f"env={env!r} plays in this process"
            )
        port = count_option("port", port, 1, 65535)
    level = chosen
    payload = load_checkpoint(path)
    spec, weights, _ = acting_parts(payload, path)
    facts = run_facts(payload, path)
    options = {**facts.pop("options"), "mode": "cooperative"}
    worker = RolloutWorker(0, env, seed, port, options, envs=min(envs, episodes))
    try:
        played = worker.run(
            Policy(spec, weights), 0,
            [Request(seed + k, 0.0, ctx, "eval") for k in range(episodes)],
        )  # fmt: skip
    finally:
        worker.close()
    return {
        **summarize(played),
        "level": level,
        "seed": seed,
        "checkpoint": str(checkpoint_path(path)),
        **facts,
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
