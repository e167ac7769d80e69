"""A reference learner to read: VDN or QMIX on one in-process arena, in one file.

    python -m neuronsmae.trainers.minimal --alg vdn --episodes 200

The package's trainer (:mod:`neuronsmae.trainers.train`) spreads the algorithm over Ray
workers and adds what a 30-minute run needs (TD(λ) targets, derived features, a per-action
head, symmetry augmentation, checkpoints). This file is the algorithm alone, top to bottom,
with the package's own agent network (:mod:`~neuronsmae.trainers.agent`) and mixers
(:mod:`~neuronsmae.trainers.mixers`):

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

from neuronsmae.protocol import ArenaAPI, EnvInfo
from neuronsmae.protocol.levels import LEVEL_ARGS, level_from_arg
from neuronsmae.trainers.agent import (
    RNNAgent,
    build_inputs,
    epsilon_at,
    epsilon_greedy,
    masked_greedy,
)
from neuronsmae.trainers.config import MAX_RUN_SEED, ConfigError
from neuronsmae.trainers.mixers import make_mixer


@dataclass(frozen=True)
class Args:
    """The reference learner's settings (``--name value`` on the command line)."""

    alg: str = "vdn"
    """vdn (the team's Q is the sum of the agents') or qmix (a monotonic mixing network)."""
    level: str = "easy"
    """Opponent bot: the paper's easy, middle or hard, or any other level a command line
    takes (protocol/levels.py: random, middle_spread, hard_flank, the released 0 and 1)."""
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
            "level": (self.level in LEVEL_ARGS, f"one of {', '.join(LEVEL_ARGS)}"),
            "seed": (0 <= self.seed <= MAX_RUN_SEED, "in [0, 2³²−1]"),
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
            raise ConfigError("; ".join(wrong))


EVAL_SEED = 1_000_000_000
"""Held-out seeds start here; training episodes use the seeds below it."""


def act(
    agent: RNNAgent, obs: list[np.ndarray], last: torch.Tensor, hidden: torch.Tensor, n_actions: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """One decision of every agent: Q-values ``[n, A]`` and the next hidden state."""
    inputs = build_inputs(
        torch.as_tensor(np.asarray(obs)), last, n_actions, last_action=True, agent_id=True
    )
    q, hidden = agent(inputs.unsqueeze(1), hidden)  # one step for each of the n agents
    return q[:, 0], hidden


@torch.no_grad()
def play(
    env: ArenaAPI,
    agent: RNNAgent,
    info: EnvInfo,
    level: str,
    seed: int,
    epsilon: float,
    generator: torch.Generator,
) -> dict[str, Any]:
    """One whole episode at exploration rate ``epsilon``; its arrays and its winner."""
    n = info.n_agents
    obs = env.reset(contexts={"level": level_from_arg(level)}, seed=seed)
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
        q, hidden = act(agent, obs, last, hidden, info.n_actions)
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


def q_values(agent: RNNAgent, batch: dict[str, torch.Tensor], n_actions: int) -> torch.Tensor:
    """Q-values of every agent at every step: ``[B, T+1, n, A]`` (agents folded into the
    batch so that one GRU call runs every sequence)."""
    last = torch.cat([torch.full_like(batch["actions"][:, :1], -1), batch["actions"]], dim=1)
    inputs = build_inputs(batch["obs"], last, n_actions, last_action=True, agent_id=True)
    b, t1, n, d = inputs.shape
    q, _ = agent(inputs.transpose(1, 2).reshape(b * n, t1, d), agent.initial_hidden(b * n))
    return q.view(b, n, t1, -1).transpose(1, 2)


class Networks(nn.Module):
    """The online agent and mixer, and their target copies."""

    def __init__(self, info: EnvInfo, args: Args) -> None:
        super().__init__()
        width = info.obs_shape + info.n_actions + info.n_agents  # obs, last action, agent id
        self.agent = RNNAgent(width, info.n_actions, args.hidden)
        self.mixer = make_mixer(args.alg, info.n_agents, info.state_shape)
        self.target_agent = copy.deepcopy(self.agent)
        self.target_mixer = copy.deepcopy(self.mixer)

    def refresh_targets(self) -> None:
        self.target_agent.load_state_dict(self.agent.state_dict())
        self.target_mixer.load_state_dict(self.mixer.state_dict())


def td_loss(
    nets: Networks, batch: dict[str, torch.Tensor], n_actions: int, gamma: float
) -> torch.Tensor:
    """Mean squared one-step TD error of the team's value over the real steps."""
    q = q_values(nets.agent, batch, n_actions)  # [B, T+1, n, A]
    taken = q[:, :-1].gather(-1, batch["actions"].unsqueeze(-1)).squeeze(-1)  # [B, T, n]
    alive = batch["alive"]  # a destroyed robot's Q carries nothing: zero it
    q_tot = nets.mixer(taken * alive[:, :-1], batch["state"][:, :-1])  # [B, T, 1]
    with torch.no_grad():
        best = masked_greedy(q[:, 1:], batch["avail"][:, 1:])  # double Q: online picks...
        target_q = q_values(nets.target_agent, batch, n_actions)[:, 1:]  # ...target values
        next_q = target_q.gather(-1, best.unsqueeze(-1)).squeeze(-1) * alive[:, 1:]
        next_tot = nets.target_mixer(next_q, batch["state"][:, 1:])  # [B, T, 1]
        # The episode's last real step ends it: no bootstrap past it.
        filled = batch["filled"]
        last = filled - torch.cat([filled[:, 1:], torch.zeros_like(filled[:, :1])], dim=1)
        target = batch["reward"].unsqueeze(-1) + gamma * (1 - last.unsqueeze(-1)) * next_tot
    filled = batch["filled"].unsqueeze(-1)
    return (((q_tot - target) * filled) ** 2).sum() / filled.sum()


def train(args: Args, env: ArenaAPI | None = None) -> dict[str, Any]:
    """Train for ``args.episodes`` episodes, then play greedily on held-out seeds.

    Returns the networks, the loss of every update and the greedy win rate.
    """
    own = env is None
    if env is None:
        from neuronsmae.server import Arena  # the in-process arena

        env = Arena(seed=args.seed, action_space="abstract")
    try:
        return _train(args, env)
    finally:
        if own:
            env.close()


def _train(args: Args, env: ArenaAPI) -> dict[str, Any]:
    """:func:`train` on an open arena."""
    random.seed(args.seed)
    torch.manual_seed(args.seed)
    generator = torch.Generator().manual_seed(args.seed)
    info = EnvInfo.from_dict(env.get_env_info())
    nets = Networks(info, args)
    params = [*nets.agent.parameters(), *nets.mixer.parameters()]
    optimizer = torch.optim.Adam(params, lr=args.lr)
    replay: deque[dict[str, Any]] = deque(maxlen=args.buffer_size)
    rng = np.random.default_rng(args.seed)
    losses: list[float] = []
    wins: deque[bool] = deque(maxlen=50)
    for k in range(args.episodes):
        epsilon = epsilon_at(k, args.eps_start, args.eps_end, args.eps_anneal)
        start = (args.seed * 100_003 + k) % EVAL_SEED  # never a held-out seed
        episode = play(env, nets.agent, info, args.level, start, epsilon, generator)
        replay.append(episode)
        wins.append(episode["winner"] == "blue")
        if len(replay) >= args.batch_size:
            picked = rng.choice(len(replay), size=args.batch_size, replace=False)
            loss = td_loss(nets, collate([replay[i] for i in picked]), info.n_actions, args.gamma)
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
    except ConfigError as exc:
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
