"""The one Q-learning core: a shared agent network, a pluggable mixer, target networks.

IQL, VDN and QMIX differ only in the mixer (:mod:`neuronsmae.trainers.core.mixers`); everything
else — the shared agent (a GRU, or the released code's MLP), one-step or TD(λ) targets with
or without double Q, hard target refreshes, the masked TD loss over padded episodes (or over
single transitions, ``T = 1``), gradient clipping — is this one class, so the three
algorithms, and this project's learner and the released one, are compared on equal terms.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from neuronsmae.protocol.env_info import EnvInfo
from neuronsmae.trainers.core.agent import (
    AGENT_NETWORKS,
    RNNAgent,
    agent_input_dim,
    build_inputs,
    masked_greedy,
)
from neuronsmae.trainers.core.buffer import Batch
from neuronsmae.trainers.core.features import (
    Featurizer,
    UnknownFeaturesError,
    action_feature_index,
    feature_dim,
    get_features,
    raw,
)
from neuronsmae.trainers.core.mixers import make_mixer


@dataclass(frozen=True)
class EnvSpec:
    """The sizes the networks and the buffer need."""

    n_agents: int
    """Agents controlled by the learner (the blue team)."""
    n_actions: int
    """Discrete choices per agent."""
    obs_dim: int
    """Length of one agent's observation after the feature set (what the buffer stores)."""
    state_dim: int
    """Length of the global state."""
    episode_limit: int
    """Decisions per episode at most."""

    @classmethod
    def of(cls, info: EnvInfo, features: str = "raw") -> EnvSpec:
        """The sizes of ``info``'s task, observations widened by the feature set ``features``."""
        return cls(
            n_agents=info.n_agents,
            n_actions=info.n_actions,
            obs_dim=feature_dim(features, info),
            state_dim=info.state_shape,
            episode_limit=info.episode_limit,
        )


@dataclass(frozen=True)
class AgentSpec:
    """How the shared agent network is built; workers rebuild it from this alone."""

    input_dim: int
    """Width of the input (observation + one-hots)."""
    n_actions: int
    """Q-values out."""
    hidden_dim: int
    """GRU width."""
    last_action: bool
    """Feed the one-hot last action."""
    agent_id: bool
    """Feed the one-hot agent index."""
    features: str = "raw"
    """Feature set applied to each observation first (:mod:`neuronsmae.trainers.core.features`)."""
    head: str = "flat"
    """Q head: flat (one linear output per action) or points (plus a per-action scorer)."""
    env_info: dict[str, Any] | None = None
    """The environment's ``get_env_info()``: the layout the features and the points head
    read (needed unless ``features='raw'`` and ``head='flat'``)."""
    network: str = "gru"
    """The agent network (:data:`~neuronsmae.trainers.core.agent.AGENT_NETWORKS`): gru or mlp."""
    masked: bool = True
    """Act within the environment's action masks; False: every action is open to the
    agents, as with the released code's all-ones masks."""

    def mask(self, avail: Any) -> Any:
        """The mask the agents act with: ``avail`` itself, or all ones when not
        :attr:`masked` (a NumPy array or a tensor of ``avail``'s shape)."""
        if self.masked:
            return avail
        return torch.ones_like(avail) if isinstance(avail, torch.Tensor) else np.ones_like(avail)

    def layout(self) -> EnvInfo:
        """The environment's layout, parsed from :attr:`env_info`."""
        if self.env_info is None:
            raise UnknownFeaturesError(
                f"features={self.features!r} with head={self.head!r} need the environment's "
                "layout: build the spec with agent_spec(..., info=EnvInfo)"
            )
        return EnvInfo.from_dict(self.env_info)

    def featurizer(self) -> Featurizer:
        """The feature function applied to each raw observation before :meth:`inputs`."""
        return raw if self.features == "raw" else get_features(self.features, self.layout())

    def inputs(self, obs: torch.Tensor, last_actions: torch.Tensor) -> torch.Tensor:
        """The network's input from featurized observations and last actions (see
        :func:`~neuronsmae.trainers.core.agent.build_inputs` for the shapes)."""
        return build_inputs(
            obs,
            last_actions,
            self.n_actions,
            last_action=self.last_action,
            agent_id=self.agent_id,
        )

    def build(self) -> RNNAgent:
        """A fresh network with this architecture (an ``RNNAgent`` or an ``MLPAgent``; both
        are called alike)."""
        index = None
        if self.head == "points":
            index = torch.as_tensor(action_feature_index(self.features, self.layout()))
        network = AGENT_NETWORKS[self.network]
        return network(self.input_dim, self.n_actions, self.hidden_dim, index)  # type: ignore[return-value]


def agent_spec(
    env: EnvSpec,
    hidden_dim: int,
    last_action: bool,
    agent_id: bool,
    features: str = "raw",
    head: str = "flat",
    info: EnvInfo | None = None,
    network: str = "gru",
    masked: bool = True,
) -> AgentSpec:
    """The agent architecture for an environment and the chosen input options.

    ``env.obs_dim`` is the width *after* the feature set (what the buffer stores); ``info``
    is the environment's layout, which the spec carries for the features and the head.
    """
    width = agent_input_dim(
        env.obs_dim,
        env.n_actions,
        env.n_agents,
        last_action=last_action,
        agent_id=agent_id,
    )
    env_info = None if info is None else info.to_dict()
    return AgentSpec(
        width, env.n_actions, hidden_dim, last_action, agent_id, features, head, env_info,
        network, masked,
    )  # fmt: skip


def sequence_q(
    agent: RNNAgent, spec: AgentSpec, batch: Batch, steps: slice = slice(None)
) -> torch.Tensor:
    """Q-values of every agent at the batch's ``steps`` (default all): ``[B, T', n, A]``.

    Agents are folded into the batch (``[B·n, T', D]``) so one call covers them all. A
    recurrent network runs the whole sequence and is sliced afterwards (its state needs
    every step); a network without memory (``spec.network == "mlp"``) is run on the asked
    steps alone, the same values at a fraction of the work.
    """
    obs, last = batch.obs, batch.last_actions
    if spec.network == "mlp":
        obs, last, steps = obs[:, steps], last[:, steps], slice(None)
    inputs = spec.inputs(obs, last)
    b, t1, n, d = inputs.shape
    flat = inputs.permute(0, 2, 1, 3).reshape(b * n, t1, d)
    q, _ = agent(flat, agent.initial_hidden(b * n))
    return q.view(b, n, t1, -1).permute(0, 2, 1, 3)[:, steps]


def lambda_returns(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_values: torch.Tensor,
    gamma: float,
    lam: float,
) -> torch.Tensor:
    """TD(λ) targets ``G_t = r_t + γ(1−d_t)[(1−λ) V_{t+1} + λ G_{t+1}]``, all ``[B, T, k]``.

    ``next_values[:, t]`` is the target network's value of the state after step ``t``, and
    the recursion starts from ``G_T = V_T``. With λ = 0 this is the one-step target. λ > 0
    carries the +20 of a win back over many steps per update instead of one, which matters
    when the budget is a few thousand episodes. Padding needs no special case: the last
    real step has ``d = 1`` and cuts the recursion, and the padded steps after it are
    masked out of the loss.

    The recursion ``G_t = a_t + b_t G_{t+1}`` (``a_t = r_t + γ(1−d_t)(1−λ)V_{t+1}``,
    ``b_t = γλ(1−d_t)``) is solved in tensors without a loop over time steps: a reverse
    scan that composes the affine maps ``G ↦ a + bG`` in ⌈log₂ T⌉ doubling rounds (after
    round r, ``(a_t, b_t)`` carries steps ``t .. t + 2^r − 1``), so an update launches a few
    dozen operations instead of one per step (:func:`lambda_returns_loop` is the recursion
    step by step, the reference it is tested against).
    """
    one_step = rewards + gamma * (1.0 - terminated) * next_values
    if lam <= 0.0:
        return one_step
    cont = (1.0 - terminated).expand_as(next_values)
    a = rewards + gamma * cont * (1.0 - lam) * next_values  # [B, T, k]
    b = gamma * lam * cont
    span = 1
    while span < a.shape[1]:  # compose each step with the one ``span`` later
        a = torch.cat([a[:, :-span] + b[:, :-span] * a[:, span:], a[:, -span:]], dim=1)
        b = torch.cat([b[:, :-span] * b[:, span:], b[:, -span:]], dim=1)
        span *= 2
    return a + b * next_values[:, -1:]


def lambda_returns_loop(
    rewards: torch.Tensor,
    terminated: torch.Tensor,
    next_values: torch.Tensor,
    gamma: float,
    lam: float,
) -> torch.Tensor:
    """:func:`lambda_returns` as the recursion reads, one step at a time from the last: the
    reference the tensor form is tested (and benchmarked) against."""
    one_step = rewards + gamma * (1.0 - terminated) * next_values
    if lam <= 0.0:
        return one_step
    out = torch.empty_like(one_step)
    carry = next_values[:, -1]
    for t in range(rewards.shape[1] - 1, -1, -1):
        blend = (1.0 - lam) * next_values[:, t] + lam * carry
        carry = rewards[:, t] + gamma * (1.0 - terminated[:, t]) * blend
        out[:, t] = carry
    return out


DEVICES = ("auto", "cpu", "cuda", "cuda:N")
"""What ``learner.device`` may name (N a CUDA device index)."""


class DeviceError(ValueError):
    """A learner device that is not a valid name, or that this machine does not have."""


def check_device_name(name: str) -> None:
    """:class:`DeviceError` unless ``name`` has one of the forms of :data:`DEVICES`."""
    kind, _, index = name.partition(":")
    if not (name in ("auto", "cpu", "cuda") or (kind == "cuda" and index.isdigit())):
        raise DeviceError(f"learner.device={name!r} is not valid; valid: {', '.join(DEVICES)}")


def resolve_device(name: str) -> torch.device:
    """The device ``name`` means here: ``auto`` is CUDA when torch sees a CUDA device and
    the CPU otherwise; ``cuda`` and ``cuda:N`` must exist (:class:`DeviceError` names what
    this machine has)."""
    check_device_name(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    device = torch.device(name)
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if device.type == "cuda" and count == 0:
        raise DeviceError(
            f"learner.device={name!r}: torch sees no CUDA device here (torch "
            f"{torch.__version__}, CUDA build: {torch.version.cuda or 'none'}); valid here: "
            "auto, cpu"
        )
    if device.type == "cuda" and (device.index or 0) >= count:
        cudas = ", ".join(["cuda", *(f"cuda:{i}" for i in range(count))])
        raise DeviceError(
            f"learner.device={name!r}: this machine has {count} CUDA device(s); valid here: "
            f"auto, cpu, {cudas}"
        )
    return device


def _on_cpu(value: Any) -> Any:
    """``value`` with every tensor in it copied to the CPU (dicts, lists and tuples walked)."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: _on_cpu(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_on_cpu(v) for v in value)
    return value


MIXER_STATES = ("state", "agent0_obs")
"""What QMIX's hypernetworks read: the environment's global state, or agent 0's observation
as its agent network sees it (the released code's ``get_state``)."""


class QLearner:
    """Trains the shared agent and the mixer from batches of padded episodes (or of one-step
    sequences: a transition replay's batches, ``T = 1``)."""

    def __init__(
        self,
        env: EnvSpec,
        spec: AgentSpec,
        mixer: str,
        *,
        lr: float,
        gamma: float,
        grad_clip: float,
        target_update_interval: int | None,
        double_q: bool,
        mixer_embed: int,
        hypernet_hidden: int,
        td_lambda: float = 0.0,
        hypernet_layers: int = 2,
        mixer_state: str = "state",
        mask_destroyed: bool = True,
        device: torch.device | str = "cpu",
    ) -> None:
        if mixer_state not in MIXER_STATES:
            raise ValueError(f"mixer_state={mixer_state!r}; valid: {', '.join(MIXER_STATES)}")
        self.env, self.spec, self.mixer_name = env, spec, mixer
        self.td_lambda = td_lambda
        self.gamma, self.grad_clip, self.double_q = gamma, grad_clip, double_q
        self.target_update_interval = target_update_interval
        """Updates between hard target refreshes; None: only when :meth:`update_targets`
        is called (the trainer's per-round cadence)."""
        self.mixer_state, self.mask_destroyed = mixer_state, mask_destroyed
        self.device = torch.device(device)
        """Where the networks, the optimiser and the batches live (acting weights and
        checkpoints are always on the CPU)."""
        self.agent = spec.build().to(self.device)
        state_dim = env.obs_dim if mixer_state == "agent0_obs" else env.state_dim
        self.mixer = make_mixer(mixer, env.n_agents, state_dim, mixer_embed, hypernet_hidden,
                                hypernet_layers).to(self.device)  # fmt: skip
        self.target_agent = copy.deepcopy(self.agent)
        self.target_mixer = copy.deepcopy(self.mixer)
        self.params = [*self.agent.parameters(), *self.mixer.parameters()]
        self.optimizer = torch.optim.Adam(self.params, lr=lr)
        self.updates = 0
        self._samples = torch.zeros((), dtype=torch.float64, device=self.device)

    def _mixer_states(self, batch: Batch) -> torch.Tensor:
        """What the mixer reads at every step ``[B, T+1, S]``."""
        return batch.obs[:, :, 0] if self.mixer_state == "agent0_obs" else batch.state

    def train(self, batch: Batch) -> dict[str, float]:
        """One gradient step on the masked TD loss; refresh the targets when due. ``batch``
        may be on the CPU or already on :attr:`device`."""
        batch = batch.to(self.device)
        self._samples = self._samples + batch.filled.sum()  # read (and synced) when asked
        # [B, T+1, n, A]; the last step only where double Q picks the next action with it
        q_all = sequence_q(self.agent, self.spec, batch, slice(None if self.double_q else -1))
        chosen = q_all[:, : batch.actions.shape[1]].gather(-1, batch.actions.unsqueeze(-1))
        chosen = chosen.squeeze(-1)  # [B, T, n]
        states = self._mixer_states(batch)
        # A destroyed robot's Q says nothing (it can only no-op): zeroed in the mixer's input
        # and left out of IQL's loss, unless the released code's choice (mask_destroyed off).
        alive = batch.alive if self.mask_destroyed else torch.ones_like(batch.alive)
        with torch.no_grad():
            target_all = sequence_q(self.target_agent, self.spec, batch, slice(1, None))
            avail_next = batch.avail[:, 1:]
            if self.double_q:
                best = masked_greedy(q_all[:, 1:].detach(), avail_next)
                target_max = target_all.gather(-1, best.unsqueeze(-1)).squeeze(-1)
            else:
                target_max = target_all.masked_fill(~avail_next, float("-inf")).max(-1).values
            target_max = torch.nan_to_num(target_max, neginf=0.0) * alive[:, 1:]
            target_tot = self.target_mixer(target_max, states[:, 1:])  # [B, T, 1 or n]
            ended = batch.terminated.unsqueeze(-1)  # [B, T, 1]
            if not self.mixer.team_output:  # IQL: a robot's own episode ends at its destruction
                ended = torch.maximum(ended, 1.0 - alive[:, 1:])  # [B, T, n]
            targets = lambda_returns(
                batch.rewards.unsqueeze(-1),
                ended,
                target_tot,
                self.gamma,
                self.td_lambda,
            )
        q_tot = self.mixer(chosen * alive[:, :-1], states[:, :-1])
        mask = batch.filled.unsqueeze(-1).expand_as(q_tot)
        if not self.mixer.team_output:  # IQL: a destroyed robot has no TD error of its own
            mask = mask * alive[:, :-1]
        td = (q_tot - targets) * mask  # [B, T, 1 or n]
        loss = (td**2).sum() / mask.sum().clamp(min=1.0)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(self.params, self.grad_clip)
        self.optimizer.step()
        self.updates += 1
        every = self.target_update_interval
        if every is not None and self.updates % every == 0:
            self.update_targets()
        count = mask.sum().clamp(min=1.0)
        taken, target = (q_tot.detach() * mask).sum() / count, (targets * mask).sum() / count
        figures = torch.stack([loss.detach(), grad_norm, taken, target]).tolist()  # one copy
        return {
            "loss": figures[0],
            "grad_norm": figures[1],
            "lr": float(self.optimizer.param_groups[0]["lr"]),
            "q_taken": figures[2],
            "target": figures[3],
        }

    @property
    def samples(self) -> int:
        """Decision steps drawn into updates so far (padding not counted)."""
        return int(self._samples)

    @samples.setter
    def samples(self, value: int) -> None:
        self._samples = torch.tensor(float(value), dtype=torch.float64, device=self.device)

    def update_targets(self) -> None:
        """Copy the online networks into the target networks (hard update)."""
        self.target_agent.load_state_dict(self.agent.state_dict())
        self.target_mixer.load_state_dict(self.mixer.state_dict())

    def acting_weights(self) -> dict[str, np.ndarray]:
        """The agent's latest weights, which sampling and evaluation act with (NumPy arrays,
        cheap to ship)."""
        return {k: v.detach().cpu().numpy().copy() for k, v in self.agent.state_dict().items()}

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume learning exactly (networks, targets, optimiser), on
        the CPU whatever :attr:`device` is, so a checkpoint loads on any device."""
        return _on_cpu(
            {
                "agent": self.agent.state_dict(),
                "mixer": self.mixer.state_dict(),
                "target_agent": self.target_agent.state_dict(),
                "target_mixer": self.target_mixer.state_dict(),
                "optimizer": self.optimizer.state_dict(),
                "updates": self.updates,
                "samples": self.samples,
            }
        )

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` saved."""
        self.agent.load_state_dict(state["agent"])
        self.mixer.load_state_dict(state["mixer"])
        self.target_agent.load_state_dict(state["target_agent"])
        self.target_mixer.load_state_dict(state["target_mixer"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.updates = int(state["updates"])
        self.samples = int(state.get("samples", 0))
