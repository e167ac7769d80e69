"""The recurrent agent network shared by all agents, its inputs, and ε-greedy action choice.

One network serves every agent (parameter sharing, as in PyMARL): a one-hot agent id in the
input lets the agents still behave differently, and the one-hot last action gives the GRU
what it needs to tell its own past choices from the environment's response. Two networks
share one interface (:data:`AGENT_NETWORKS`): the GRU (this project's default) and the
released code's MLP, which sees the current input alone.

The GRU is an ``nn.GRU`` rather than a ``GRUCell`` loop: the inputs of a stored episode are
all known in advance (the last actions come from the buffer), so the learner runs the whole
sequence in one fused call, which on a CPU is several times faster than stepping in Python.
Acting calls the same module one step at a time.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from neuronsmae.protocol.errors import NeuronsMAEError


class PolicyInputError(NeuronsMAEError, ValueError):
    """What an acting policy was given does not fit it: observations or action masks of the
    wrong shape, not numbers, or not finite; a mask that is not 0/1 or leaves an agent no
    available action; arena indices out of range or named twice. The message names the
    argument, the shape or range expected and what was given."""

    code = "invalid_policy_input"


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


def one_hot_width(spec: Any, n_agents: int) -> int:
    """Input columns of ``spec``'s network (an ``AgentSpec``) after the observation's: the
    one-hot last action and agent index it feeds (:func:`agent_input_dim` with no
    observation)."""
    return agent_input_dim(0, spec.n_actions, n_agents, last_action=spec.last_action,
                           agent_id=spec.agent_id)  # fmt: skip


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


class _QNetwork(nn.Module):
    """What the agent networks share: a linear Q output per action on the last hidden layer,
    and the optional points head.

    Both networks take ``inputs [B, T, D]`` and a recurrent state ``hidden [1, B, H]`` and
    return ``q [B, T, n_actions]`` and the next state, so acting and learning call either the
    same way. B counts (episode, agent) pairs, so agents are folded into the batch.
    """

    def __init__(self, input_dim: int, hidden_dim: int) -> None:
        super().__init__()
        self.hidden_dim = hidden_dim
        self.fc1 = nn.Linear(input_dim, hidden_dim)
        self.point_head: nn.Module | None = None

    def _add_point_head(self, action_index: torch.Tensor | None, head_hidden: int) -> None:
        """The points head, built last (after the layers a subclass adds, which keeps the
        order in which a seeded run draws the initial weights)."""
        if action_index is not None:
            # ``action_index [A, F]``: which input columns describe action a's target and
            # point. One small MLP scores every action from (last hidden layer, those
            # columns), so what it learns about one candidate point transfers to all eight.
            self.register_buffer("action_index", action_index.long(), persistent=False)
            self.point_head = nn.Sequential(
                nn.Linear(self.hidden_dim + action_index.shape[1], head_hidden),
                nn.ReLU(),
                nn.Linear(head_hidden, 1),
            )

    def _q(self, out: torch.Tensor, inputs: torch.Tensor) -> torch.Tensor:
        """Q-values ``[B, T, A]`` from the last hidden layer ``out [B, T, H]``."""
        q = self.fc2(out)
        if self.point_head is not None:
            # index_select on the flattened index: the same columns as inputs[..., index],
            # in about 0.6 of the time
            per_action = inputs.index_select(-1, self.action_index.flatten())
            q = q + self._score_points(out, per_action.unflatten(-1, self.action_index.shape))
        return q

    def _score_points(self, out: torch.Tensor, per_action: torch.Tensor) -> torch.Tensor:
        """The point head on ``[out, per_action]`` for every action: ``[B, T, A]``.

        ``out [B, T, H]`` is shared by the A actions, so the first layer's product with it is
        taken once per step and broadcast, instead of once per action on a concatenated
        ``[B, T, A, H + F]`` tensor: the same function and parameters at about a ninth of the
        cost of the largest matrix product of an update. The ``[B, T, A, head_hidden]``
        activations, the largest tensors of an update, are written once: the broadcast sum
        and the ReLU in place (neither product's gradient reads them), and the last layer
        (one output) as a product with its weight vector, whose gradient is a broadcast
        product rather than a matrix product with an inner size of one.
        """
        assert self.point_head is not None
        first, _, last = self.point_head  # Linear, ReLU, Linear(head_hidden, 1)
        w_out, w_act = first.weight.split([self.hidden_dim, per_action.shape[-1]], dim=1)
        pre = F.linear(per_action, w_act)
        pre += F.linear(out, w_out, first.bias).unsqueeze(-2)
        return torch.matmul(torch.relu_(pre), last.weight[0]) + last.bias[0]


def score_points_sum(self: _QNetwork, out: torch.Tensor, per_action: torch.Tensor) -> torch.Tensor:
    """:meth:`_QNetwork._score_points` as first written (a new broadcast sum, the ReLU
    module and the last ``Linear``): the same function and gradients, kept for the tests and
    ``bench.bench_learner --reference``, which compare the faster form with it."""
    assert self.point_head is not None
    first, act, last = self.point_head
    w_out, w_act = first.weight.split([self.hidden_dim, per_action.shape[-1]], dim=1)
    pre = F.linear(out, w_out, first.bias).unsqueeze(-2) + F.linear(per_action, w_act)
    return last(act(pre)).squeeze(-1)


class RNNAgent(_QNetwork):
    """``Linear → ReLU → GRU → Linear``: one Q-value per action for every agent (PyMARL's
    agent; this project's default, ``learner.agent_net="gru"``).

    Shapes: ``inputs [B, T, D]`` and ``hidden [1, B, H]`` → ``q [B, T, n_actions]`` and the
    new ``hidden [1, B, H]``; H is ``hidden_dim``.
    """

    def __init__(
        self,
        input_dim: int,
        n_actions: int,
        hidden_dim: int = 128,
        action_index: torch.Tensor | None = None,
        head_hidden: int = 64,
    ) -> None:
        super().__init__(input_dim, hidden_dim)
        self.rnn = nn.GRU(hidden_dim, hidden_dim, batch_first=True)
        self.fc2 = nn.Linear(hidden_dim, n_actions)
        self._add_point_head(action_index, head_hidden)

    def initial_hidden(self, batch: int) -> torch.Tensor:
        """A zero hidden state ``[1, batch, H]`` for the start of an episode."""
        return torch.zeros(1, batch, self.hidden_dim, device=self.fc1.weight.device)

    def forward(
        self, inputs: torch.Tensor, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Run ``T`` steps; return the Q-values ``[B, T, A]`` and the last hidden state."""
        out, hidden = self.rnn(F.relu(self.fc1(inputs)), hidden)
        return self._q(out, inputs), hidden


class MLPAgent(_QNetwork):
    """``Linear → ReLU → Linear → ReLU → Linear``: Q-values from the current input alone
    (the released code's agent, network/qmix_net.py's ``myRNN``, which has no recurrence;
    ``learner.agent_net="mlp"``).

    It keeps the recurrent interface, so every caller runs it as it runs :class:`RNNAgent`:
    the state it takes and returns is a constant zero ``[1, B, 1]`` that carries nothing.
    """

    def __init__(
        self,
        input_dim: int,
        n_actions: int,
        hidden_dim: int = 128,
        action_index: torch.Tensor | None = None,
        head_hidden: int = 64,
    ) -> None:
        super().__init__(input_dim, hidden_dim)
        self.fc_mid = nn.Linear(hidden_dim, hidden_dim)
        self.fc2 = nn.Linear(hidden_dim, n_actions)
        self._add_point_head(action_index, head_hidden)

    def initial_hidden(self, batch: int) -> torch.Tensor:
        """The constant state ``[1, batch, 1]`` (zeros; the network has no memory)."""
        return torch.zeros(1, batch, 1, device=self.fc1.weight.device)

    def forward(
        self, inputs: torch.Tensor, hidden: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Q-values ``[B, T, A]`` of every step on its own; ``hidden`` comes back as given."""
        out = F.relu(self.fc_mid(F.relu(self.fc1(inputs))))
        return self._q(out, inputs), hidden


AGENT_NETWORKS: dict[str, type[_QNetwork]] = {"gru": RNNAgent, "mlp": MLPAgent}
"""The agent networks by ``learner.agent_net`` name."""


def _given(value: Any) -> str:
    """``value`` as an error message describes it: its shape, or its type and repr."""
    if isinstance(value, (np.ndarray, torch.Tensor)):
        return f"an array of shape {list(value.shape)} ({value.dtype})"
    return f"{type(value).__name__} {value!r:.60}"


def _dims(axes: Sequence[str], shape: tuple[int, ...]) -> str:
    """``["n_agents", "obs_dim"]``, ``(2, 37)`` → ``"[n_agents=2, obs_dim=37]"``."""
    return "[" + ", ".join(f"{a}={n}" for a, n in zip(axes, shape, strict=True)) + "]"


def observations(obs: Any, shape: tuple[int, ...], axes: Sequence[str]) -> np.ndarray:
    """``obs`` as float32 of ``shape`` (``axes`` names its dimensions for the message),
    finite; else :class:`PolicyInputError`. No copy when it already is float32."""
    try:
        x = np.asarray(obs, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise PolicyInputError(
            f"obs must be numbers of shape {_dims(axes, shape)}, got {_given(obs)}"
        ) from exc
    if x.shape != shape:
        raise PolicyInputError(f"obs must have shape {_dims(axes, shape)}, got {_given(obs)}")
    if not np.isfinite(x).all():
        raise PolicyInputError(
            f"obs must be finite numbers, got NaN or infinite values in {_dims(axes, shape)}"
        )
    return x


def action_mask(
    avail: Any, shape: tuple[int, ...], axes: Sequence[str], arenas: Sequence[int] | None = None
) -> torch.Tensor:
    """``avail`` (1/True = available, 0/False = not) as a bool tensor of ``shape`` (``axes``
    names its dimensions), every agent with at least one available action; else
    :class:`PolicyInputError` naming the agent (and its arena: ``arenas`` lists the arena
    of each leading row)."""
    try:
        a = np.asarray(avail)
    except ValueError:  # ragged rows
        a = np.empty(0, object)
    if a.shape != shape or a.dtype.kind not in "biuf":
        raise PolicyInputError(
            f"avail must be a 0/1 mask of shape {_dims(axes, shape)}, got {_given(avail)}"
        )
    kind = a.dtype.kind
    if kind == "f":
        binary = bool(((a == 0) | (a == 1)).all())
    else:  # two reductions instead of comparisons for integers
        binary = kind == "b" or not a.size or bool(a.min() >= 0 and a.max() <= 1)
    if not binary:
        bad = a[(a != 0) & (a != 1)][0].item()
        raise PolicyInputError(f"avail must hold 0 or 1 (or booleans) only, got {bad!r}")
    some = a.any(axis=-1)
    if not some.all():
        where = [int(i) for i in np.argwhere(~some)[0]]
        agent = f"agent {where[-1]}"
        if arenas is not None:
            agent += f" in arena {int(arenas[where[0]])}"
        raise PolicyInputError(
            f"avail: {agent} has no available action (its mask row is all 0); the "
            "environment allows at least the no-op, so the mask is not one it gave"
        )
    return torch.from_numpy(a if kind == "b" else a.astype(bool))


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
    :class:`PolicyInputError` (a ``ValueError``) naming the row of an agent that has none
    available, which the environment contract rules out.
    """
    allowed = avail > 0
    some = allowed.any(dim=-1)
    if not bool(some.all()):
        row = int((~some).nonzero()[0, 0])
        raise PolicyInputError(
            f"avail: agent row {row} has no available action; the env must allow at least no-op"
        )
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
