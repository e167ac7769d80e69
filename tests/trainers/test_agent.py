"""Agent inputs and ε-greedy: never an unavailable action, whatever ε and Q."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neuronsmae.trainers.agent import (
    RNNAgent,
    build_inputs,
    epsilon_at,
    epsilon_greedy,
    masked_greedy,
)


@st.composite
def q_and_masks(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    n = draw(st.integers(1, 4))
    a = draw(st.integers(1, 9))
    q = np.array(draw(st.lists(st.floats(-1e6, 1e6), min_size=n * a, max_size=n * a)))
    bits = draw(st.lists(st.booleans(), min_size=n * a, max_size=n * a))
    mask = np.array(bits, dtype=np.int8).reshape(n, a)
    mask[np.arange(n), draw(st.lists(st.integers(0, a - 1), min_size=n, max_size=n))] = 1
    return q.reshape(n, a).astype(np.float32), mask


@settings(max_examples=200, deadline=None)
@given(q_and_masks(), st.floats(0.0, 1.0), st.integers(0, 2**31 - 1))
def test_epsilon_greedy_only_picks_available(
    qm: tuple[np.ndarray, np.ndarray], eps: float, seed: int
) -> None:
    q, mask = qm
    gen = torch.Generator().manual_seed(seed)
    actions = epsilon_greedy(torch.from_numpy(q), torch.from_numpy(mask), eps, gen)
    assert actions.shape == (q.shape[0],)
    assert all(mask[i, a] == 1 for i, a in enumerate(actions.tolist()))


def test_greedy_ignores_better_unavailable_action() -> None:
    q = torch.tensor([[9.0, 1.0, 2.0]])
    avail = torch.tensor([[0, 1, 1]], dtype=torch.int8)
    assert masked_greedy(q, avail > 0).item() == 2
    gen = torch.Generator().manual_seed(0)
    assert epsilon_greedy(q, avail, 0.0, gen).item() == 2


def test_no_available_action_is_an_error() -> None:
    with pytest.raises(ValueError, match="no available action"):
        epsilon_greedy(torch.zeros(1, 3), torch.zeros(1, 3), 0.5, torch.Generator())


def test_inputs_and_network_shapes() -> None:
    obs = torch.randn(4, 7, 2, 37)  # [B, T, n, obs]
    last = torch.full((4, 7, 2), -1, dtype=torch.int64)
    last[:, 1:] = 3
    x = build_inputs(obs, last, 8, last_action=True, agent_id=True)
    assert x.shape == (4, 7, 2, 37 + 8 + 2)
    assert x[:, 0, :, 37:45].sum() == 0  # no last action before the first step
    assert (x[:, 1:, :, 37 + 3] == 1).all()
    assert torch.equal(x[0, 0, :, 45:], torch.eye(2))
    agent = RNNAgent(47, 8, 16)
    q, h = agent(x.permute(0, 2, 1, 3).reshape(8, 7, 47), agent.initial_hidden(8))
    assert q.shape == (8, 7, 8) and h.shape == (1, 8, 16)


def test_epsilon_schedule() -> None:
    assert epsilon_at(0, 0.2, 0.05, 100) == pytest.approx(0.2)
    assert epsilon_at(50, 0.2, 0.05, 100) == pytest.approx(0.125)
    assert epsilon_at(500, 0.2, 0.05, 100) == pytest.approx(0.05)
