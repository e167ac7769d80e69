"""A reference learner to read: VDN or QMIX on one in-process arena, in one file.

    python -m neuronsmae.trainers.minimal --alg vdn --episodes 200

The package's trainer (:mod:`neuronsmae.trainers.run.train`) spreads the algorithm over Ray
workers and adds what a 30-minute run needs (TD(λ) targets, derived features, a per-action
head, symmetry augmentation, checkpoints). This file is the algorithm alone, top to bottom,
self-contained in the manner of CleanRL: NumPy, PyTorch and, of this package, only the
client's factory of an in-process arena (``make_arena("inprocess")``); the networks, the
mixers and ε-greedy are written out here.

1. **Act.** One GRU network, shared by the agents, maps each agent's observation (plus its
   last action and its index) to a Q-value per action; agents act ε-greedily among the
   actions the arena allows.
2. **Store.** Whole episodes go to a replay of the most recent ones (a recurrent agent
   learns from sequences, so the unit is the episode).
3. **Learn.** From a batch of stored episodes: the Q-values of the actions taken, mixed into
   the team's value ``Q_tot`` (VDN: their sum; QMIX: a monotonic network of the global
   state), regressed on the one-step target ``r + γ · Q_tot'(s', a')`` where a target
   network values the next step's greedy actions (double Q-learning).
4. **Refresh.** Every ``target_every`` updates the target networks copy the online ones.

No Ray, no checkpoints; at the end the greedy policy plays held-out seeds.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import math
import random
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from neuronsmae.client import make_arena

MAX_SEED = 2**32 - 1
"""Largest run seed (NumPy's, Python's and torch's generators take it as it is)."""
LEVELS = ("0", "1", "easy", "middle", "hard", "random", "middle_spread", "hard_flank")
"""The bots a command line names (docs/contexts.md, "Bots"); "0" and "1" are the released
build's levels, sent as numbers."""


@dataclass(frozen=True)
class Args:
    """The reference learner's settings (``--name value`` on the command line)."""

    alg: str = "vdn"
    """vdn (the team's Q is the sum of the agents') or qmix (a monotonic mixing network)."""
    level: str = "easy"
    """Opponent bot: the paper's easy, middle or hard, or any other level a command line
    takes (random, middle_spread, hard_flank, the released 0 and 1)."""
    episodes: int = 200
    """Training episodes."""
    seed: int = 1
    """Seeds the networks, exploration and the episodes' starts."""
    lr: float = 5e-4
    """Adam learning rate (paper: 5e-4)."""
    gamma: float = 0.99
    """Discount (paper: 0.99)."""
    eps_start: float = 0.2
    """Exploration ε at the start (paper: 0.2), falling linearly to ``eps_end``."""
    eps_end: float = 0.05
    """Exploration ε after ``eps_anneal`` episodes (paper: 0.05)."""
    eps_anneal: int = 100
    """Episodes over which ε falls."""
    buffer_size: int = 1000
    """Episodes kept for replay."""
    batch_size: int = 16
    """Episodes per update; learning starts once the replay holds this many."""
    target_every: int = 50
    """Updates between target-network refreshes."""
    hidden: int = 64
    """GRU width (paper: 128)."""
    grad_clip: float = 10.0
    """Gradient-norm clip (paper: 10)."""
    eval_episodes: int = 20
    """Greedy episodes on held-out seeds at the end."""

    def __post_init__(self) -> None:
        """Refuse a setting outside its range, naming it and the range."""
        valid = {
            "alg": (self.alg in ("vdn", "qmix"), "vdn or qmix"),
            "level": (self.level in LEVELS, f"one of {', '.join(LEVELS)}"),
            "seed": (0 <= self.seed <= MAX_SEED, "in [0, 2³²−1]"),
            "lr": (0 < self.lr < math.inf, "a finite number > 0"),
            "gamma": (0 <= self.gamma <= 1, "in [0, 1]"),
            "eps_start": (0 <= self.eps_start <= 1, "in [0, 1]"),
            "eps_end": (0 <= self.eps_end <= 1, "in [0, 1]"),
            "grad_clip": (0 < self.grad_clip < math.inf, "a finite number > 0"),
            "buffer_size": (self.buffer_size >= self.batch_size, "≥ batch_size"),
        }
        for name in ("episodes", "eps_anneal", "batch_size", "target_every", "hidden",
                     "eval_episodes"):  # fmt: skip
            valid[name] = (getattr(self, name) >= 1, "an integer ≥ 1")
        wrong = [f"{k} must be {what}, got {getattr(self, k)!r}" for k, (ok, what) in
                 valid.items() if not ok]  # fmt: skip
        if wrong:
            raise ValueError("; ".join(wrong))


EVAL_SEED = 1_000_000_000
"""Held-out seeds start here; training episodes use the seeds below it."""


class Agent(nn.Module):
    """The agent network shared by every agent: ``Linear → ReLU → GRU → Linear``, one
    Q-value per action. Its input is the agent's observation, its one-hot last action and
    its one-hot index, so the agents can still behave differently."""

    def __init__(self, obs_dim: int, n_actions: int, n_agents: int, hidden: int) -> None:
        super().__init__()
        self.n_actions, self.n_agents, self.hidden = n_actions, n_agents, hidden
        self.fc1 = nn.Linear(obs_dim + n_actions + n_agents, hidden)
        self.rnn = nn.GRU(hidden, hidden, batch_first=True)
        self.fc2 = nn.Linear(hidden, n_actions)

    def inputs(self, obs: torch.Tensor, last: torch.Tensor) -> torch.Tensor:
        """``obs [..., n, D]`` and last actions ``[..., n]`` (−1 before the first) →
        ``[..., n, D + A + n]``."""
        one_hot = F.one_hot(last.clamp(min=0), self.n_actions).to(obs.dtype)
        one_hot = one_hot * (last >= 0).unsqueeze(-1).to(obs.dtype)
        ids = torch.eye(self.n_agents, dtype=obs.dtype).expand(*obs.shape[:-1], self.n_agents)
        return torch.cat([obs, one_hot, ids], dim=-1)

    def initial_hidden(self, batch: int) -> torch.Tensor:
        return torch.zeros(1, batch, self.hidden)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``x [B, T, input]``, ``h [1, B, H]`` → Q ``[B, T, A]`` and the next ``h``."""
        out, h = self.rnn(F.relu(self.fc1(x)), h)
        return self.fc2(out), h


class QMixer(nn.Module):
    """QMIX's mixer: ``Q_tot = w2ᵀ ELU(W1ᵀ q + b1) + b2``, the weights made non-negative
    from the global state by hypernetworks, so ``Q_tot`` grows with every agent's Q."""

    def __init__(self, n_agents: int, state_dim: int, embed: int = 32, hidden: int = 64) -> None:
        super().__init__()
        self.n, self.embed = n_agents, embed
        self.w1 = nn.Sequential(nn.Linear(state_dim, hidden), nn.ReLU(),
                                nn.Linear(hidden, n_agents * embed))  # fmt: skip
        self.w2 = nn.Sequential(nn.Linear(state_dim, hidden), nn.ReLU(), nn.Linear(hidden, embed))
        self.b1 = nn.Linear(state_dim, embed)
        self.b2 = nn.Sequential(nn.Linear(state_dim, embed), nn.ReLU(), nn.Linear(embed, 1))

    def forward(self, q: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """``q [B, T, n]``, ``state [B, T, S]`` → ``[B, T, 1]``."""
        b, t, n = q.shape
        s = state.reshape(b * t, -1)
        w1 = self.w1(s).abs().view(-1, n, self.embed)
        hidden = F.elu(torch.bmm(q.reshape(-1, 1, n), w1) + self.b1(s).view(-1, 1, self.embed))
        w2 = self.w2(s).abs().view(-1, self.embed, 1)
        return (torch.bmm(hidden, w2) + self.b2(s).view(-1, 1, 1)).view(b, t, 1)


class VDNMixer(nn.Module):
    """VDN's mixer: the team's Q is the sum of the agents' Qs."""

    def forward(self, q: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        return q.sum(dim=-1, keepdim=True)


def epsilon_greedy(
    q: torch.Tensor, avail: torch.Tensor, epsilon: float, generator: torch.Generator
) -> torch.Tensor:
    """One action per agent: a uniform choice among the available ones with probability ε,
    else the available action of highest Q. ``q``, ``avail`` ``[n, A]`` → ``[n]``."""
    greedy = q.masked_fill(avail <= 0, float("-inf")).argmax(dim=-1)
    random_pick = torch.multinomial(avail.to(torch.float64), 1, generator=generator)[:, 0]
    explore = torch.rand(q.shape[0], generator=generator) < epsilon
    return torch.where(explore, random_pick, greedy)


def level_context(level: str) -> int | str:
    """The ``level`` context of a command-line level: the released levels are numbers."""
    return int(level) if level in ("0", "1") else level


EVAL_SEED = 1_000_000_000
"""Held-out seeds start here; training episodes use the seeds below it."""


def act(
    agent: Agent, obs: list[np.ndarray], last: torch.Tensor, hidden: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """One decision of every agent: Q-values ``[n, A]`` and the next hidden state."""
    inputs = agent.inputs(torch.as_tensor(np.asarray(obs, np.float32)), last)
    q, hidden = agent(inputs.unsqueeze(1), hidden)  # one step for each of the n agents
    return q[:, 0], hidden


@torch.no_grad()
def play(
    env: Any,
    agent: Agent,
    info: dict[str, Any],
    level: str,
    seed: int,
    epsilon: float,
    generator: torch.Generator,
) -> dict[str, Any]:
    """One whole episode at exploration rate ``epsilon``; its arrays and its winner."""
    n = info["n_agents"]
    obs = env.reset(contexts={"level": level_context(level)}, seed=seed)
    hidden, last = agent.initial_hidden(n), torch.full((n,), -1)
    steps: dict[str, list[Any]] = {
        "obs": [obs],
        "state": [env.get_state()],
        "actions": [],
        "avail": [env.get_avail_actions()],
        "reward": [],
        "alive": [np.ones(n)],
    }
    done, result = False, {}
    while not done:
        q, hidden = act(agent, obs, last, hidden)
        avail = torch.as_tensor(np.asarray(steps["avail"][-1]))
        last = epsilon_greedy(q, avail, epsilon, generator)
        obs, reward, done, result = env.step(last.tolist())
        steps["obs"].append(obs)
        steps["state"].append(env.get_state())
        steps["avail"].append(env.get_avail_actions())
        steps["actions"].append(last.numpy())
        steps["reward"].append(reward[0])  # every agent gets the team's reward
        steps["alive"].append(np.asarray(result["alive"][:n], np.float32))
    episode = {k: np.asarray(v, np.float32) for k, v in steps.items()}
    episode["actions"] = episode["actions"].astype(np.int64)
    return {**episode, "winner": result["winner"]}


def collate(episodes: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Pad episodes of ``T_i`` decisions to the longest ``T``; ``filled`` marks real steps.

    Shapes: obs ``[B, T+1, n, D]``, state ``[B, T+1, S]``, avail ``[B, T+1, n, A]``, alive
    ``[B, T+1, n]``, actions ``[B, T, n]``, reward and filled ``[B, T]``.
    """
    t = max(len(e["reward"]) for e in episodes)
    out: dict[str, list[np.ndarray]] = {k: [] for k in (*episodes[0], "filled") if k != "winner"}
    for e in episodes:
        pad = t - len(e["reward"])
        for key in ("obs", "state", "avail", "alive", "actions", "reward"):
            widths = [(0, pad)] + [(0, 0)] * (e[key].ndim - 1)
            fill = 1.0 if key == "avail" else 0.0  # padded steps: any action, masked out later
            out[key].append(np.pad(e[key], widths, constant_values=fill))
        out["filled"].append(np.r_[np.ones(t - pad), np.zeros(pad)].astype(np.float32))
    return {k: torch.as_tensor(np.stack(v)) for k, v in out.items()}


def q_values(agent: Agent, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Q-values of every agent at every step: ``[B, T+1, n, A]`` (agents folded into the
    batch so that one GRU call runs every sequence)."""
    last = torch.cat([torch.full_like(batch["actions"][:, :1], -1), batch["actions"]], dim=1)
    inputs = agent.inputs(batch["obs"], last)
    b, t1, n, d = inputs.shape
    q, _ = agent(inputs.transpose(1, 2).reshape(b * n, t1, d), agent.initial_hidden(b * n))
    return q.view(b, n, t1, -1).transpose(1, 2)


class Networks(nn.Module):
    """The online agent and mixer, and their target copies."""

    def __init__(self, info: dict[str, Any], args: Args) -> None:
        super().__init__()
        n, actions = info["n_agents"], info["n_actions"]
        self.agent = Agent(info["obs_shape"], actions, n, args.hidden)
        self.mixer = QMixer(n, info["state_shape"]) if args.alg == "qmix" else VDNMixer()
        self.target_agent = copy.deepcopy(self.agent)
        self.target_mixer = copy.deepcopy(self.mixer)

    def refresh_targets(self) -> None:
        self.target_agent.load_state_dict(self.agent.state_dict())
        self.target_mixer.load_state_dict(self.mixer.state_dict())


def td_loss(nets: Networks, batch: dict[str, torch.Tensor], gamma: float) -> torch.Tensor:
    """Mean squared one-step TD error of the team's value over the real steps."""
    q = q_values(nets.agent, batch)  # [B, T+1, n, A]
    taken = q[:, :-1].gather(-1, batch["actions"].unsqueeze(-1)).squeeze(-1)  # [B, T, n]
    alive = batch["alive"]  # a destroyed robot's Q carries nothing: zero it
    q_tot = nets.mixer(taken * alive[:, :-1], batch["state"][:, :-1])  # [B, T, 1]
    with torch.no_grad():
        masked = q[:, 1:].masked_fill(batch["avail"][:, 1:] <= 0, float("-inf"))
        best = masked.argmax(dim=-1)  # double Q: the online network picks...
        target_q = q_values(nets.target_agent, batch)[:, 1:]  # ...the target network values
        next_q = target_q.gather(-1, best.unsqueeze(-1)).squeeze(-1) * alive[:, 1:]
        next_tot = nets.target_mixer(next_q, batch["state"][:, 1:])  # [B, T, 1]
        # The episode's last real step ends it: no bootstrap past it.
        filled = batch["filled"]
        last = filled - torch.cat([filled[:, 1:], torch.zeros_like(filled[:, :1])], dim=1)
        target = batch["reward"].unsqueeze(-1) + gamma * (1 - last.unsqueeze(-1)) * next_tot
    filled = batch["filled"].unsqueeze(-1)
    return (((q_tot - target) * filled) ** 2).sum() / filled.sum()


def train(args: Args, env: Any = None) -> dict[str, Any]:
    """Train for ``args.episodes`` episodes, then play greedily on held-out seeds.

    Returns the networks, the loss of every update and the greedy win rate.
    """
    own = env is None
    if env is None:  # the in-process arena, through the client's factory
        env = make_arena("inprocess", seed=args.seed, action_space="abstract")
    try:
        return _train(args, env)
    finally:
        if own:
            env.close()


def _train(args: Args, env: Any) -> dict[str, Any]:
    """:func:`train` on an open arena."""
    random.seed(args.seed)
    torch.manual_seed(args.seed)
    generator = torch.Generator().manual_seed(args.seed)
    info = env.get_env_info()
    nets = Networks(info, args)
    params = [*nets.agent.parameters(), *nets.mixer.parameters()]
    optimizer = torch.optim.Adam(params, lr=args.lr)
    replay: deque[dict[str, Any]] = deque(maxlen=args.buffer_size)
    rng = np.random.default_rng(args.seed)
    losses: list[float] = []
    wins: deque[bool] = deque(maxlen=50)
    for k in range(args.episodes):
        epsilon = args.eps_start + min(k / args.eps_anneal, 1.0) * (args.eps_end - args.eps_start)
        start = (args.seed * 100_003 + k) % EVAL_SEED  # never a held-out seed
        episode = play(env, nets.agent, info, args.level, start, epsilon, generator)
        replay.append(episode)
        wins.append(episode["winner"] == "blue")
        if len(replay) >= args.batch_size:
            picked = rng.choice(len(replay), size=args.batch_size, replace=False)
            loss = td_loss(nets, collate([replay[i] for i in picked]), args.gamma)
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(params, args.grad_clip)
            optimizer.step()
            losses.append(float(loss.detach()))
            if len(losses) % args.target_every == 0:
                nets.refresh_targets()
        if (k + 1) % 20 == 0:
            print(
                f"episode {k + 1}: ε {epsilon:.3f}, win rate (last 50) "
                f"{np.mean(wins):.2f}, loss {losses[-1] if losses else float('nan'):.4f}",
                flush=True,
            )
    won = [
        play(env, nets.agent, info, args.level, EVAL_SEED + k, 0.0, generator)["winner"] == "blue"
        for k in range(args.eval_episodes)
    ]
    return {"networks": nets, "losses": losses, "win_rate": float(np.mean(won))}


def parse_args(argv: list[str] | None = None) -> Args:
    """``--name value`` for every field of :class:`Args`."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    for f in dataclasses.fields(Args):
        parser.add_argument(
            f"--{f.name.replace('_', '-')}",
            type=type(f.default),
            default=f.default,
            help=f"default: {f.default}",
        )
    try:
        return Args(**vars(parser.parse_args(argv)))
    except ValueError as exc:
        parser.error(str(exc))


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    result = train(args)
    print(
        f"{args.alg} against the {args.level} bot after {args.episodes} episodes: greedy "
        f"win rate {result['win_rate']:.2f} over {args.eval_episodes} held-out episodes"
    )


if __name__ == "__main__":
    main()
