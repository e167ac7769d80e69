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

import dataclasses
import os
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
import torch

T = TypeVar("T")


class IncompleteEpisodeError(ValueError):
    """An episode with missing steps, inconsistent shapes or no terminal step."""


class ReplayStateError(ValueError):
    """A saved replay does not fit the buffer it is loaded into (capacity, shapes, types)."""


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

    def to(self, device: torch.device) -> Batch:
        """This batch on ``device`` in one host-to-device transfer (itself on the CPU): the
        fields packed into one buffer (:meth:`packed`), pinned on CUDA so the copy runs
        asynchronously, sent once, and viewed back as the fields (:meth:`unpacked`)."""
        if device.type == "cpu":
            return self
        packed, layout = self.packed()
        if device.type == "cuda":
            packed = packed.pin_memory()
        return Batch.unpacked(packed.to(device, non_blocking=True), layout)

    def packed(self) -> tuple[torch.Tensor, list[tuple[str, torch.dtype, torch.Size]]]:
        """Every field's bytes in one contiguous ``uint8`` tensor, widest types first (so each
        field starts aligned for its type), and the layout :meth:`unpacked` reads back."""
        fields = sorted(
            (f.name for f in dataclasses.fields(self)), key=lambda n: -getattr(self, n).itemsize
        )
        parts = [getattr(self, name).contiguous() for name in fields]
        data = torch.cat([p.reshape(-1).view(torch.uint8) for p in parts])
        return data, [(name, p.dtype, p.shape) for name, p in zip(fields, parts, strict=True)]

    @staticmethod
    def unpacked(data: torch.Tensor, layout: list[tuple[str, torch.dtype, torch.Size]]) -> Batch:
        """The batch :meth:`packed` gave as ``data`` and ``layout``: views, no copies."""
        out, start = {}, 0
        for name, dtype, shape in layout:
            size = shape.numel() * dtype.itemsize
            out[name] = data[start : start + size].view(dtype).view(shape)
            start += size
        return Batch(**out)


class _Ring(ABC):
    """What both replays share: ring-buffer counters, and their contents as arrays that a
    checkpoint can save (:meth:`state_dict`) and a resumed run load (:meth:`load_state_dict`)."""

    capacity: int
    next_slot: int
    size: int
    added: int

    @abstractmethod
    def arrays(self) -> dict[str, np.ndarray]:
        """The storage by name, one row per slot (filled or not)."""

    def state_dict(self) -> dict[str, Any]:
        """The stored rows (the first ``size`` slots; the ring's order is kept by
        ``next_slot``) and the counters: NumPy arrays and ints only."""
        rows = {name: a[: self.size] for name, a in self.arrays().items()}
        return {"next_slot": self.next_slot, "size": self.size, "added": self.added, **rows}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore :meth:`state_dict`'s contents into this (empty or not) buffer; refused
        with :class:`ReplayStateError` if they do not fit its capacity and shapes."""
        size, arrays = int(state["size"]), self.arrays()
        if not 0 <= size <= self.capacity or not 0 <= int(state["next_slot"]) < self.capacity:
            raise ReplayStateError(
                f"a replay of {size} items (next slot {state['next_slot']}) does not fit a "
                f"capacity of {self.capacity}"
            )
        for name, a in arrays.items():
            rows = np.asarray(state[name])
            if rows.shape != (size, *a.shape[1:]) or rows.dtype != a.dtype:
                raise ReplayStateError(
                    f"replay array {name!r}: {rows.dtype}{list(rows.shape)} where this task "
                    f"stores {a.dtype}{[size, *a.shape[1:]]}"
                )
        for name, a in arrays.items():
            a[:size] = state[name]
            a[size:] = 0
        self.next_slot, self.size, self.added = int(state["next_slot"]), size, int(state["added"])


class EpisodeReplayBuffer(_Ring):
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
        _check_memory(capacity, "episode", per_episode)
        z = {k: np.zeros((capacity, *shape), dtype) for k, (shape, dtype) in arrays.items()}
        self.obs, self.state, self.avail, self.alive = z["obs"], z["state"], z["avail"], z["alive"]
        self.actions, self.rewards = z["actions"], z["rewards"]
        self.terminated, self.filled, self.lengths = z["terminated"], z["filled"], z["lengths"]
        self.next_slot = 0
        self.size = 0
        self.added = 0

    def __len__(self) -> int:
        return self.size

    def arrays(self) -> dict[str, np.ndarray]:
        names = ("obs", "state", "avail", "alive", "actions", "rewards", "terminated",
                 "filled", "lengths")  # fmt: skip
        return {name: getattr(self, name) for name in names}

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


def transition_arrays(
    n_agents: int, obs_dim: int, state_dim: int, n_actions: int
) -> dict[str, tuple[tuple[int, ...], type[np.generic]]]:
    """Each array a :class:`TransitionReplayBuffer` stores per transition: its shape and
    dtype. Index 0 of the leading 2 is the decision's step, 1 the step after it."""
    n = n_agents
    return {
        "obs": ((2, n, obs_dim), np.float32),
        "state": ((2, state_dim), np.float32),
        "avail": ((2, n, n_actions), np.bool_),
        "alive": ((2, n), np.float32),
        "actions": ((n,), np.int64),
        "last_actions": ((n,), np.int64),
        "rewards": ((), np.float32),
        "terminated": ((), np.float32),
    }


def _check_memory(capacity: int, unit: str, per_item: int) -> None:
    """Refuse a buffer larger than the memory available (:class:`ReplayMemoryError`):
    NumPy's zeros are allocated lazily, so without this the run would be killed only once
    the buffer filled, hours in."""
    available = available_memory()
    if available is not None and capacity * per_item > available:
        raise ReplayMemoryError(
            f"{capacity} {unit}s of replay need {capacity * per_item / 2**30:.1f} GiB "
            f"({per_item / 2**10:.1f} KiB each for this task) and this machine has "
            f"{available / 2**30:.1f} GiB available; at most {available // per_item} "
            f"{unit}s fit"
        )


class TransitionReplayBuffer(_Ring):
    """A ring buffer of the last ``capacity`` single transitions (the released code's
    replay, common/replay_buffer.py: 200,000 transitions; ``learner.replay="transitions"``).

    It takes whole :class:`Episode` s like :class:`EpisodeReplayBuffer` and keeps each
    decision as ``(o_t, s_t, masks_t, u_t, r_t, o_{t+1}, s_{t+1}, masks_{t+1}, done_t)``;
    ``len()`` counts transitions. :meth:`sample` draws uniformly with replacement and
    returns a :class:`Batch` of one-step sequences (``T = 1``), so the one Q-learner trains
    on it unchanged. Only a network without memory (``agent_net="mlp"``) can learn from it.
    """

    def __init__(
        self, capacity: int, n_agents: int, obs_dim: int, state_dim: int, n_actions: int,
        episode_limit: int,
    ) -> None:  # fmt: skip
        if capacity < 1:
            raise ValueError(f"buffer capacity must be ≥ 1, got {capacity}")
        self.capacity = capacity
        self.dims = (n_agents, obs_dim, state_dim, n_actions, episode_limit)
        arrays = transition_arrays(n_agents, obs_dim, state_dim, n_actions)
        per = sum(int(np.prod(shape)) * np.dtype(d).itemsize for shape, d in arrays.values())
        _check_memory(capacity, "transition", per)
        self.data = {k: np.zeros((capacity, *shape), d) for k, (shape, d) in arrays.items()}
        self.next_slot = 0
        self.size = 0
        self.added = 0
        """Transitions stored since the buffer was made (the overwritten ones included)."""

    def __len__(self) -> int:
        return self.size

    def arrays(self) -> dict[str, np.ndarray]:
        return self.data

    def add(self, episode: Episode) -> None:
        """Validate an episode and store each of its decisions, overwriting the oldest
        transitions when full."""
        episode.validate(*self.dims)
        steps = episode.length
        slots = (self.next_slot + np.arange(steps)) % self.capacity
        last = np.concatenate([np.full((1, self.dims[0]), -1), episode.actions[:-1]])
        done = np.zeros(steps, np.float32)
        done[-1] = 1.0
        rows = {
            "obs": np.stack([episode.obs[:-1], episode.obs[1:]], axis=1),
            "state": np.stack([episode.state[:-1], episode.state[1:]], axis=1),
            "avail": np.stack([episode.avail[:-1], episode.avail[1:]], axis=1) > 0,
            "alive": np.stack([episode.alive[:-1], episode.alive[1:]], axis=1),
            "actions": episode.actions,
            "last_actions": last,
            "rewards": episode.rewards,
            "terminated": done,
        }
        for name, values in rows.items():
            self.data[name][slots] = values
        self.next_slot = int((self.next_slot + steps) % self.capacity)
        self.size = min(self.size + steps, self.capacity)
        self.added += steps

    def sample(self, batch_size: int, rng: np.random.Generator) -> Batch:
        """Draw ``min(batch_size, len(self))`` transitions uniformly with replacement (the
        released code's ``np.random.randint`` over what is stored)."""
        if self.size == 0:
            raise ValueError("cannot sample from an empty buffer")
        idx = rng.integers(0, self.size, size=min(batch_size, self.size))
        d = {k: torch.from_numpy(v[idx]) for k, v in self.data.items()}
        actions = d["actions"].unsqueeze(1)  # [B, 1, n]
        return Batch(
            obs=d["obs"],
            state=d["state"],
            avail=d["avail"],
            alive=d["alive"],
            actions=actions,
            last_actions=torch.cat([d["last_actions"].unsqueeze(1), actions], dim=1),
            rewards=d["rewards"].unsqueeze(1),
            terminated=d["terminated"].unsqueeze(1),
            filled=torch.ones_like(d["rewards"]).unsqueeze(1),
        )


PREFETCH = ("auto", "on", "off")
"""``learner.prefetch``'s values (:func:`prefetch_pays`)."""


def prefetch_pays(setting: str, device: torch.device) -> bool:
    """Whether the next batch is made in a background thread (``learner.prefetch``): on,
    off, or auto: when the learner leaves a core for it (a CUDA device, or fewer intra-op
    threads than this process may use). On a machine whose cores the update's own threads
    fill, the thread takes a core from them (and spinning OpenMP threads wait for it)."""
    if setting != "auto":
        return setting == "on"
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return device.type == "cuda" or torch.get_num_threads() < (cores or 1)


def prefetched(make: Callable[[], T], n: int, background: bool = True) -> Iterator[T]:
    """``make()`` called ``n`` times, each call made in a background thread while the caller
    works with the previous result: a batch is sampled, augmented and sent to the learner's
    device while the previous one trains (torch releases the GIL in its kernels). The calls
    run one after another, in order, so a seeded generator they draw from gives the same
    batches as calling ``make`` inline, which is what ``background=False`` does."""
    if n <= 0:
        return
    if not background:
        for _ in range(n):
            yield make()
        return
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="prefetch") as pool:
        pending = pool.submit(make)
        for i in range(n):
            ready = pending.result()
            if i + 1 < n:
                pending = pool.submit(make)
            yield ready


REPLAYS: dict[str, type] = {"episodes": EpisodeReplayBuffer, "transitions": TransitionReplayBuffer}
"""The replay buffers by ``learner.replay`` name; both take the same arguments (capacity in
episodes or in transitions)."""
