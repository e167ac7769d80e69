"""The episode buffer's padding and masks, and its refusal of partial episodes."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import torch

from neuronsmae.trainers.core import buffer as buffer_module
from neuronsmae.trainers.core.buffer import (
    EpisodeReplayBuffer,
    IncompleteEpisodeError,
    ReplayMemoryError,
    ReplayStateError,
    TransitionReplayBuffer,
)

from ..conftest import ACTIONS, LIMIT, N_AGENTS, OBS, STATE, make_episode


def _buffer(capacity: int = 4) -> EpisodeReplayBuffer:
    return EpisodeReplayBuffer(capacity, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)


def test_masks_for_short_episode_and_destroyed_agent() -> None:
    rng = np.random.default_rng(0)
    buf = _buffer(1)
    buf.add(make_episode(4, rng, dead_from=2))
    b = buf.sample(1, rng)
    assert b.obs.shape == (1, 5, N_AGENTS, OBS)  # cut to the longest episode: T = 4
    assert b.filled[0].tolist() == [1, 1, 1, 1]
    assert b.terminated[0].tolist() == [0, 0, 0, 1]
    assert b.alive[0, :, 0].tolist() == [1, 1, 1, 1, 1]
    assert b.alive[0, :, 1].tolist() == [1, 1, 0, 0, 0]
    assert b.last_actions[0, 0].tolist() == [-1, -1]
    assert b.last_actions[0, 1:].tolist() == b.actions[0].tolist()


def test_padding_after_episode_end() -> None:
    rng = np.random.default_rng(1)
    buf = _buffer(2)
    buf.add(make_episode(2, rng))
    buf.add(make_episode(LIMIT, rng))
    b = buf.sample(16, rng)  # with replacement: both episodes appear
    assert {int(b.filled[i].sum()) for i in range(16)} == {2, LIMIT}
    for i in range(16):
        steps = int(b.filled[i].sum())
        assert b.filled[i, :steps].eq(1).all() and b.filled[i, steps:].eq(0).all()
        assert b.terminated[i].sum() == 1 and b.terminated[i, steps - 1] == 1
        assert b.alive[i, steps + 1 :].eq(0).all()
        assert b.avail[i, steps + 1 :].eq(False).all()


def test_ring_overwrites_oldest_and_clears_old_padding() -> None:
    rng = np.random.default_rng(2)
    buf = _buffer(1)
    buf.add(make_episode(LIMIT, rng))
    buf.add(make_episode(3, rng))
    assert len(buf) == 1 and buf.added == 2
    assert buf.filled[0].tolist() == [1, 1, 1, 0, 0, 0]
    assert not buf.obs[0, 4:].any()


@pytest.mark.parametrize(
    "broken",
    ["partial", "missing_obs", "too_long", "unavailable_action"],
)
def test_rejects_incomplete_episodes(broken: str) -> None:
    rng = np.random.default_rng(3)
    ep = make_episode(3, rng, terminated=broken != "partial")
    if broken == "missing_obs":
        ep.obs = ep.obs[:-1]
    elif broken == "too_long":
        ep = make_episode(LIMIT + 1, rng)
    elif broken == "unavailable_action":
        ep.avail[0, 0] = [1, 0, 0]
        ep.actions[0, 0] = 2
    buf = _buffer()
    with pytest.raises(IncompleteEpisodeError):
        buf.add(ep)
    assert len(buf) == 0


def test_uniform_sampling_draws_with_the_generator_given() -> None:
    buf = _buffer(4)
    rng = np.random.default_rng(3)
    for _ in range(4):
        buf.add(make_episode(LIMIT, rng))
    b = buf.sample(3, np.random.default_rng(9))
    expected = np.random.default_rng(9).choice(4, size=3, replace=False)
    assert torch.equal(b.obs, torch.from_numpy(buf.obs[expected, : b.obs.shape[1]]))


def test_a_buffer_larger_than_the_available_memory_is_refused_with_what_fits(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """NumPy allocates the zeros lazily, so a too-large buffer failed only when it filled."""
    one = EpisodeReplayBuffer(1, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    per_episode = sum(getattr(one, k).nbytes for k in buffer_module.episode_arrays(*one.dims))
    monkeypatch.setattr(buffer_module, "available_memory", lambda: 10 * per_episode + 5)
    assert EpisodeReplayBuffer(10, N_AGENTS, OBS, STATE, ACTIONS, LIMIT).capacity == 10
    with pytest.raises(ReplayMemoryError, match=r"11 episodes of replay need .* at most 10 "):
        EpisodeReplayBuffer(11, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    monkeypatch.setattr(buffer_module, "available_memory", lambda: None)  # not Linux: no check
    assert EpisodeReplayBuffer(11, N_AGENTS, OBS, STATE, ACTIONS, LIMIT).capacity == 11
    monkeypatch.undo()
    if sys.platform == "linux":  # the real figure: MemAvailable, in bytes
        assert 2**20 < (buffer_module.available_memory() or 0) < 2**50


@pytest.mark.parametrize("kind", [EpisodeReplayBuffer, TransitionReplayBuffer])
@pytest.mark.parametrize("episodes", [2, 7])  # partly filled, and wrapped round
def test_a_replay_saved_and_loaded_draws_what_the_original_draws(
    kind: type[EpisodeReplayBuffer | TransitionReplayBuffer], episodes: int
) -> None:
    rng = np.random.default_rng(5)
    capacity = 4 if kind is EpisodeReplayBuffer else 20
    original = kind(capacity, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(episodes):
        original.add(make_episode(LIMIT, rng, dead_from=2))
    state = original.state_dict()
    assert all(isinstance(v, (int, np.ndarray)) for v in state.values())
    copy = kind(capacity, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    copy.add(make_episode(LIMIT, rng))  # whatever it held is replaced
    copy.load_state_dict(state)
    assert (len(copy), copy.next_slot, copy.added) == (len(original), original.next_slot,
                                                       original.added)  # fmt: skip
    a, b = original.sample(5, np.random.default_rng(1)), copy.sample(5, np.random.default_rng(1))
    for name in ("obs", "state", "avail", "alive", "actions", "rewards", "filled"):
        assert torch.equal(getattr(a, name), getattr(b, name)), name
    new = make_episode(LIMIT, rng)  # and both go on alike: the same slot is overwritten next
    original.add(new)
    copy.add(new)
    for name, array in original.arrays().items():
        assert np.array_equal(array, copy.arrays()[name]), name


def test_a_saved_replay_that_does_not_fit_is_refused_with_what_differs() -> None:
    rng = np.random.default_rng(6)
    big = EpisodeReplayBuffer(8, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(6):
        big.add(make_episode(LIMIT, rng))
    with pytest.raises(ReplayStateError, match=r"6 items .* capacity of 4"):
        _buffer(4).load_state_dict(big.state_dict())
    other = EpisodeReplayBuffer(8, N_AGENTS, OBS + 1, STATE, ACTIONS, LIMIT)
    with pytest.raises(ReplayStateError, match="replay array 'obs'"):
        other.load_state_dict(big.state_dict())
