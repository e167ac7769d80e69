"""Whole-episode replay: episodes as the workers return them, and a padded ring buffer.

Recurrent agents must be trained on whole sequences, so the unit of storage is the episode
(as in PyMARL). Episodes have different lengths (a team can be wiped out before the 50th
decision), so each is padded to ``episode_limit`` and carries masks:

* ``filled [T]`` — 1 for real decision steps, 0 for padding after the episode ended;
* ``terminated [T]`` — 1 on the last step of an episode that ended (no bootstrapping).
  Every episode ends so, the time limit included: the referee decides the winner by HP at
  the limit and pays its ±20 then, and the time is in the observation and the state, so the
  limit is part of the game, not a cut of it. (The Gymnasium and PettingZoo faces report
  it as ``truncated``, with SMAC's ``episode_limit``, for learners that bootstrap there.)
* ``alive [T+1, n]`` — 1 while the robot is alive: a destroyed robot can only take its
  no-op, so its Q carries no information; the learner zeroes it in the mixer's input and
  drops it from IQL's per-agent loss, and IQL ends a robot's own return (one-step and
  λ-return alike) at its destruction.

An :class:`Episode` is validated before it is stored, so a partial episode from a worker
whose env died mid-run can never enter the buffer. Batches are drawn uniformly (the paper's
and PyMARL's buffer).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch


class IncompleteEpisodeError(ValueError):
    """An episode with missing steps, inconsistent shapes or no terminal step."""


class ReplayMemoryError(ValueError):
    """A replay buffer larger than the memory this machine has available."""


def episode_arrays(
    n_agents: int, obs_dim: int, state_dim: int, n_actions: int, episode_limit: int
) -> dict[str, tuple[tuple[int, ...], type[np.generic]]]:
    """Each array the buffer stores per episode: its shape (padded to ``episode_limit``
    decisions) and dtype."""
    t, n = episode_limit, n_agents
    return {
        "obs": ((t + 1, n, obs_dim), np.float32),
        "state": ((t + 1, state_dim), np.float32),
        "avail": ((t + 1, n, n_actions), np.bool_),
        "alive": ((t + 1, n), np.float32),
        "actions": ((t, n), np.int64),
        "rewards": ((t,), np.float32),
        "terminated": ((t,), np.float32),
        "filled": ((t,), np.float32),
        "lengths": ((), np.int64),
    }


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux's ``MemAvailable``), or None
    where the system does not say."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


@dataclass
class Episode:
    """One finished episode of ``L`` decisions for ``n`` agents (unpadded).

    Arrays carry one more row than there are decisions where the value after the last
    decision is needed for the TD target (observation, state, masks at ``t = L``).
    """

    obs: np.ndarray
    """``[L+1, n, obs_dim]`` float32 observations (row ``L``: after the last decision)."""
    state: np.ndarray
    """``[L+1, state_dim]`` float32 global states."""
    avail: np.ndarray
    """``[L+1, n, n_actions]`` int8 available-action masks."""
    alive: np.ndarray
    """``[L+1, n]`` bool: the robot was alive when the decision was taken."""
    actions: np.ndarray
    """``[L, n]`` int64 actions taken."""
    rewards: np.ndarray
    """``[L]`` float32 team rewards (the env gives every team member the same)."""
    terminated: bool
    """The env reported ``done`` after the last decision."""
    info: dict[str, Any] = field(default_factory=dict)
    """Outcome for the records: ``winner``, ``seed``, ``epsilon``, ``worker``."""

    @property
    def length(self) -> int:
        """Number of decisions ``L``."""
        return int(self.actions.shape[0])

    @property
    def total_reward(self) -> float:
        """Undiscounted team return of the episode."""
        return float(self.rewards.sum())

    def validate(
        self, n_agents: int, obs_dim: int, state_dim: int, n_actions: int, episode_limit: int
    ) -> None:
        """Raise :class:`IncompleteEpisodeError` unless every step is present and consistent."""
        steps = self.length
        expected = {
            "obs": (steps + 1, n_agents, obs_dim),
            "state": (steps + 1, state_dim),
            "avail": (steps + 1, n_agents, n_actions),
            "alive": (steps + 1, n_agents),
            "actions": (steps, n_agents),
            "rewards": (steps,),
        }
        for name, shape in expected.items():
            got = getattr(self, name).shape
            if got != shape:
                raise IncompleteEpisodeError(f"episode field {name} has shape {got}, not {shape}")
        if not 1 <= steps <= episode_limit:
            raise IncompleteEpisodeError(f"episode has {steps} steps; valid: 1..{episode_limit}")
        if not self.terminated:
            raise IncompleteEpisodeError("episode did not end with done; it is partial")
        taken = np.take_along_axis(self.avail[:-1], self.actions[..., None], axis=-1)
        if (self.actions < 0).any() or (taken <= 0).any():
            raise IncompleteEpisodeError("episode holds an action that was not available")


@dataclass
class Batch:
    """A training batch of ``B`` padded episodes cut to the longest one (``T`` steps)."""

    obs: torch.Tensor
    """``[B, T+1, n, obs_dim]`` float32."""
    state: torch.Tensor
    """``[B, T+1, state_dim]`` float32."""
    avail: torch.Tensor
    """``[B, T+1, n, A]`` bool."""
    alive: torch.Tensor
    """``[B, T+1, n]`` float32 (1 alive, 0 destroyed or padding)."""
    actions: torch.Tensor
    """``[B, T, n]`` int64 (0 in padding)."""
    last_actions: torch.Tensor
    """``[B, T+1, n]`` int64: the action before each step, ``-1`` at ``t = 0``."""
    rewards: torch.Tensor
    """``[B, T]`` float32."""
    terminated: torch.Tensor
    """``[B, T]`` float32."""
    filled: torch.Tensor
    """``[B, T]`` float32."""


class EpisodeReplayBuffer:
    """A ring buffer of the last ``capacity`` episodes, stored padded to ``episode_limit``."""

    def __init__(
        self,
        capacity: int,
        n_agents: int,
        obs_dim: int,
        state_dim: int,
        n_actions: int,
        episode_limit: int,
    ) -> None:
        if capacity < 1:
            raise ValueError(f"buffer capacity must be ≥ 1, got {capacity}")
        self.capacity = capacity
        self.dims = (n_agents, obs_dim, state_dim, n_actions, episode_limit)
        arrays = episode_arrays(*self.dims)
        per_episode = sum(
            int(np.prod(shape)) * np.dtype(d).itemsize for shape, d in arrays.values()
        )
        available = available_memory()
        if available is not None and capacity * per_episode > available:
            # NumPy's zeros are allocated lazily: without this the run would be killed only
            # once the buffer filled, hours in.
            raise ReplayMemoryError(
                f"{capacity} episodes of replay need {capacity * per_episode / 2**30:.1f} GiB "
                f"({per_episode / 2**10:.0f} KiB each for this task) and this machine has "
                f"{available / 2**30:.1f} GiB available; at most "
                f"{available // per_episode} episodes fit"
            )
        z = {k: np.zeros((capacity, *shape), dtype) for k, (shape, dtype) in arrays.items()}
        self.obs, self.state, self.avail, self.alive = z["obs"], z["state"], z["avail"], z["alive"]
        self.actions, self.rewards = z["actions"], z["rewards"]
        self.terminated, self.filled, self.lengths = z["terminated"], z["filled"], z["lengths"]
        self.next_slot = 0
        self.size = 0
        self.added = 0

    def __len__(self) -> int:
        return self.size

    def add(self, episode: Episode) -> None:
        """Validate and store one episode, overwriting the oldest when full."""
        episode.validate(*self.dims)
        i, steps = self.next_slot, episode.length
        for name in (
            "obs",
            "state",
            "avail",
            "alive",
            "actions",
            "rewards",
            "terminated",
            "filled",
        ):
            getattr(self, name)[i] = 0
        self.obs[i, : steps + 1] = episode.obs
        self.state[i, : steps + 1] = episode.state
        self.avail[i, : steps + 1] = episode.avail > 0
        self.alive[i, : steps + 1] = episode.alive
        self.actions[i, :steps] = episode.actions
        self.rewards[i, :steps] = episode.rewards
        self.filled[i, :steps] = 1.0
        self.terminated[i, steps - 1] = 1.0
        self.lengths[i] = steps
        self.next_slot = (i + 1) % self.capacity
        self.size = min(self.size + 1, self.capacity)
        self.added += 1

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """Draw ``batch_size`` stored episodes uniformly (with replacement if too few)."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty buffer")
        idx = rng.choice(self.size, size=batch_size, replace=self.size < batch_size)
        steps = int(self.lengths[idx].max())
        actions = torch.from_numpy(self.actions[idx, :steps])
        first = torch.full_like(actions[:, :1], -1)
        return Batch(
            obs=torch.from_numpy(self.obs[idx, : steps + 1]),
            state=torch.from_numpy(self.state[idx, : steps + 1]),
            avail=torch.from_numpy(self.avail[idx, : steps + 1]),
            alive=torch.from_numpy(self.alive[idx, : steps + 1]),
            actions=actions,
            last_actions=torch.cat([first, actions], dim=1),
            rewards=torch.from_numpy(self.rewards[idx, :steps]),
            terminated=torch.from_numpy(self.terminated[idx, :steps]),
            filled=torch.from_numpy(self.filled[idx, :steps]),
        )
