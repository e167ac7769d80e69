"""The recurrent agent network shared by all agents, its inputs, and ε-greedy action choice.

One network serves every agent (parameter sharing, as in PyMARL): a one-hot agent id in the
input lets the agents still behave differently, and the one-hot last action gives the GRU
what it needs to tell its own past choices from the environment's response.

The GRU is an ``nn.GRU`` rather than a ``GRUCell`` loop: the inputs of a stored episode are
all known in advance (the last actions come from the buffer), so the learner runs the whole
sequence in one fused call, which on a CPU is several times faster than stepping in Python.
Acting calls the same module one step at a time.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F


def agent_input_dim(
    obs_dim: int,
    n_actions: int,
    n_agents: int,
    *,
    last_action: bool,
    agent_id: bool,
) -> int:
    """Width of the agent network's input: observation, then the optional one-hots."""
    return obs_dim + (n_actions if last_action else 0) + (n_agents if agent_id else 0)


def build_inputs(
    obs: torch.Tensor,
    last_actions: torch.Tensor,
    n_actions: int,
    *,
    last_action: bool,
    agent_id: bool,
) -> torch.Tensor:
    """Concatenate the agent network's inputs.

    ``obs [..., n_agents, obs_dim]`` (float) and ``last_actions [..., n_agents]`` (int64, the
    action taken at the previous decision, ``-1`` before the first) → ``[..., n_agents, D]``
    with D from :func:`agent_input_dim`. A ``-1`` last action becomes an all-zero one-hot.
    The columns are: observation, own last action, agent id; the observation comes first so
    that feature column indices (the points head's) are input column indices.
    """
    parts = [obs]
    n_agents = obs.shape[-2]
    onehot = F.one_hot(last_actions.clamp(min=0), n_actions).to(obs.dtype)
    onehot = onehot * (last_actions >= 0).unsqueeze(-1).to(obs.dtype)  # [..., n, A]
    if last_action:
        parts.append(onehot)
    if agent_id:
        ids = torch.eye(n_agents, dtype=obs.dtype, device=obs.device)
        parts.append(ids.expand(*obs.shape[:-1], n_agents))
    return torch.cat(parts, dim=-1)


class RNNAgent(nn.Module):
    """``Linear → ReLU → GRU → Linear``: one Q-value per action for every agent.

    Shapes: ``inputs [B, T, D]`` and ``hidden [1, B, H]`` → ``q [B, T, n_actions]`` and the
    new ``hidden [1, B, H]``. B counts (episode, agent) pairs, so agents are folded into the
    batch; H is ``hidden_dim``.
    """

    def __init__(
        self,
        input_dim: int,
        n_actions: int,
        hidden_dim: int = 128,
        action_index: torch.Tensor | None = None,
        head_hidden: int = 64,
    ) -> None:
        super().__init__()
        self.hidden_dim = hidden_dim
        self.fc1 = nn.Linear(input_dim, hidden_dim)
        self.rnn = nn.GRU(hidden_dim, hidden_dim, batch_first=True)
        self.fc2 = nn.Linear(hidden_dim, n_actions)
        self.point_head: nn.Module | None = None
        if action_index is not None:
            # ``action_index [A, F]``: which input columns describe action a's target and
            # point. One small MLP scores every action from (GRU output, those columns), so
            # what it learns about one candidate point transfers to all eight.
            self.register_buffer("action_index", action_index.long(), persistent=False)
            self.point_head = nn.Sequential(
                nn.Linear(hidden_dim + action_index.shape[1], head_hidden),
                nn.ReLU(),
                nn.Linear(head_hidden, 1),
            )

    def initial_hidden(self, batch: int) -> torch.Tensor:
        """A zero hidden state ``[1, batch, H]`` for the start of an episode."""
        return torch.zeros(1, batch, self.hidden_dim, device=self.fc1.weight.device)

    def forward(
        self, inputs: torch.Tensor, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Run ``T`` steps; return the Q-values ``[B, T, A]`` and the last hidden state."""
        x = F.relu(self.fc1(inputs))
        out, hidden = self.rnn(x, hidden)
        q = self.fc2(out)
        if self.point_head is not None:
            q = q + self._score_points(out, inputs[..., self.action_index])
        return q, hidden

    def _score_points(self, out: torch.Tensor, per_action: torch.Tensor) -> torch.Tensor:
        """The point head on ``[out, per_action]`` for every action: ``[B, T, A]``.

        ``out [B, T, H]`` is shared by the A actions, so the first layer's product with it is
        taken once per step and broadcast, instead of once per action on a concatenated
        ``[B, T, A, H + F]`` tensor: the same function and parameters at about a ninth of the
        cost of the largest matrix product of an update.
        """
        assert self.point_head is not None
        first, act, last = self.point_head
        w_out, w_act = first.weight.split([self.hidden_dim, per_action.shape[-1]], dim=1)
        pre = F.linear(out, w_out, first.bias).unsqueeze(-2) + F.linear(per_action, w_act)
        return last(act(pre)).squeeze(-1)


def masked_greedy(q: torch.Tensor, avail: torch.Tensor) -> torch.Tensor:
    """Index of the best *available* action: ``q [..., A]``, ``avail [..., A]`` → ``[...]``."""
    return q.masked_fill(avail <= 0, float("-inf")).argmax(dim=-1)


def epsilon_greedy(
    q: torch.Tensor,
    avail: torch.Tensor,
    epsilon: float | torch.Tensor,
    generator: torch.Generator,
) -> torch.Tensor:
    """Pick one action per agent: uniform over the available ones with probability ε.

    ``q [n, A]`` and ``avail [n, A]`` (1 = allowed) → ``actions [n]`` (int64). ``epsilon`` is
    one rate for every row or a ``[n]`` tensor of rates (a batched worker's rows belong to
    episodes at different ε). Exploration draws only among available actions, so a
    destroyed robot always gets its no-op and an unavailable action is never sent. Raises
    ``ValueError`` if an agent has none available, which the environment contract rules out.
    """
    allowed = avail > 0
    if not bool(allowed.any(dim=-1).all()):
        raise ValueError("an agent has no available action; the env must allow at least no-op")
    greedy = masked_greedy(q, allowed)
    if not bool(torch.as_tensor(epsilon).gt(0.0).any()):
        return greedy
    random_pick = torch.multinomial(allowed.to(torch.float64), 1, generator=generator).squeeze(-1)
    explore = torch.rand(q.shape[0], generator=generator) < epsilon
    return torch.where(explore, random_pick, greedy)


def epsilon_at(episode: int, start: float, end: float, anneal_episodes: int) -> float:
    """Linear ε schedule over episodes: ``start`` at 0, ``end`` from ``anneal_episodes`` on."""
    if anneal_episodes <= 0:
        return end
    frac = min(max(episode / anneal_episodes, 0.0), 1.0)
    return start + frac * (end - start)
