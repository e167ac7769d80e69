"""Value-decomposition mixers for the one Q-learner, chosen by name through a small registry.

EPyMARL style: there is one Q-learning core (:mod:`neuronsmae.trainers.core.learner`) and the
algorithm is only the mixer that turns the agents' chosen Q-values into the team's Q:

* ``"none"`` → IQL: no mixing; every agent is trained on its own Q with the team reward.
* ``"vdn"`` → VDN: ``Q_tot = Σ_i Q_i`` (Sunehag et al., 2017).
* ``"qmix"`` → QMIX: a monotonic two-layer mixing network whose weights come from
  hypernetworks fed with the true global state (Rashid et al., 2018).

Shapes (every mixer): ``agent_qs`` is ``[B, T, n_agents]`` (the chosen action's Q of each
agent), ``states`` is ``[B, T, state_dim]`` (``ArenaAPI.get_state``), and the result is
``[B, T, 1]`` for VDN and QMIX, or ``[B, T, n_agents]`` for the identity mixer (IQL keeps
one TD error per agent). B is the batch of episodes and T the decision steps.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn
from torch.nn import functional as F


class UnknownMixerError(ValueError):
    """A mixer or algorithm name that the registry does not hold."""


class IdentityMixer(nn.Module):
    """IQL: pass every agent's Q through unchanged so each agent has its own TD target."""

    team_output = False
    """False: the output keeps one column per agent (``[B, T, n_agents]``)."""

    def forward(self, agent_qs: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
        """``agent_qs [B, T, n]``, ``states [B, T, S]`` (unused) → ``[B, T, n]``."""
        del states
        return agent_qs


class VDNMixer(nn.Module):
    """VDN: the team's Q is the plain sum of the agents' Qs (no parameters)."""

    team_output = True

    def forward(self, agent_qs: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
        """``agent_qs [B, T, n]``, ``states [B, T, S]`` (unused) → ``Q_tot [B, T, 1]``."""
        del states
        return agent_qs.sum(dim=-1, keepdim=True)


class QMixer(nn.Module):
    """QMIX: ``Q_tot = w2ᵀ ELU(W1ᵀ q + b1) + b2`` with ``W1, w2 ≥ 0`` made from the state.

    The absolute value on the hypernetworks' weight outputs is what makes ``Q_tot``
    monotonic (non-decreasing) in every agent's Q, so each agent's greedy action is also the
    team's greedy action. The biases may be negative; they do not affect monotonicity. The
    weight hypernetworks have two layers (``hypernet_hidden`` wide) or one.
    """

    team_output = True

    def __init__(
        self,
        n_agents: int,
        state_dim: int,
        embed_dim: int = 32,
        hypernet_hidden: int = 64,
        hypernet_layers: int = 2,
    ) -> None:
        super().__init__()
        self.n_agents = n_agents
        self.state_dim = state_dim
        self.embed_dim = embed_dim
        if hypernet_layers == 2:  # PyMARL's ``hypernet_layers=2``
            self.hyper_w1: nn.Module = nn.Sequential(
                nn.Linear(state_dim, hypernet_hidden),
                nn.ReLU(),
                nn.Linear(hypernet_hidden, n_agents * embed_dim),
            )
            self.hyper_w2: nn.Module = nn.Sequential(
                nn.Linear(state_dim, hypernet_hidden),
                nn.ReLU(),
                nn.Linear(hypernet_hidden, embed_dim),
            )
        elif hypernet_layers == 1:  # one linear layer each (the released code's)
            self.hyper_w1 = nn.Linear(state_dim, n_agents * embed_dim)
            self.hyper_w2 = nn.Linear(state_dim, embed_dim)
        else:
            raise ValueError(f"hypernet_layers must be 1 or 2, got {hypernet_layers!r}")
        self.hyper_b1 = nn.Linear(state_dim, embed_dim)
        self.hyper_b2 = nn.Sequential(
            nn.Linear(state_dim, embed_dim), nn.ReLU(), nn.Linear(embed_dim, 1)
        )

    def forward(self, agent_qs: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
        """``agent_qs [B, T, n]``, ``states [B, T, S]`` → ``Q_tot [B, T, 1]``.

        Internally: ``q [B·T, 1, n]``, ``W1 [B·T, n, E]``, ``b1 [B·T, 1, E]``,
        ``hidden [B·T, 1, E]``, ``w2 [B·T, E, 1]``, ``b2 [B·T, 1, 1]`` with E = embed_dim.
        """
        batch, steps, n = agent_qs.shape
        s = states.reshape(-1, self.state_dim)
        q = agent_qs.reshape(-1, 1, n)
        w1 = torch.abs(self.hyper_w1(s)).view(-1, n, self.embed_dim)
        b1 = self.hyper_b1(s).view(-1, 1, self.embed_dim)
        hidden = F.elu(torch.bmm(q, w1) + b1)
        w2 = torch.abs(self.hyper_w2(s)).view(-1, self.embed_dim, 1)
        b2 = self.hyper_b2(s).view(-1, 1, 1)
        return (torch.bmm(hidden, w2) + b2).view(batch, steps, 1)


MixerFactory = Callable[[int, int, int, int, int], nn.Module]
"""``(n_agents, state_dim, embed_dim, hypernet_hidden, hypernet_layers) → mixer``."""

MIXERS: dict[str, MixerFactory] = {
    "none": lambda n, s, e, h, layers: IdentityMixer(),
    "vdn": lambda n, s, e, h, layers: VDNMixer(),
    "qmix": lambda n, s, e, h, layers: QMixer(n, s, e, h, layers),
}
"""The registry: mixer name → factory. Register a new mixer by adding an entry here."""

ALGORITHMS: dict[str, str] = {"iql": "none", "vdn": "vdn", "qmix": "qmix"}
"""Algorithm name on the command line → mixer name in :data:`MIXERS`."""


def mixer_for_algorithm(alg: str) -> str:
    """The mixer name behind an algorithm name; raise listing the valid algorithms."""
    try:
        return ALGORITHMS[alg]
    except KeyError:
        raise UnknownMixerError(
            f"unknown algorithm {alg!r}; valid: {', '.join(sorted(ALGORITHMS))}"
        ) from None


def make_mixer(
    name: str,
    n_agents: int,
    state_dim: int,
    embed_dim: int = 32,
    hypernet_hidden: int = 64,
    hypernet_layers: int = 2,
) -> nn.Module:
    """Build the mixer registered as ``name``; raise listing the registered names."""
    try:
        factory = MIXERS[name]
    except KeyError:
        raise UnknownMixerError(
            f"unknown mixer {name!r}; valid: {', '.join(sorted(MIXERS))}"
        ) from None
    return factory(n_agents, state_dim, embed_dim, hypernet_hidden, hypernet_layers)
