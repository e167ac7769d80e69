"""Agent inputs and ε-greedy: never an unavailable action, whatever ε and Q."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from neuronsmae.trainers.core.agent import (
    MLPAgent,
    PolicyInputError,
    RNNAgent,
    _QNetwork,
    action_mask,
    build_inputs,
    epsilon_at,
    epsilon_greedy,
    masked_greedy,
    observations,
    score_points_sum,
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
    avail = torch.ones(3, 3)
    avail[2] = 0
    with pytest.raises(PolicyInputError, match="agent row 2 has no available action"):
        epsilon_greedy(torch.zeros(3, 3), avail, 0.5, torch.Generator())
    assert issubclass(PolicyInputError, ValueError)


@settings(max_examples=100, deadline=None)
@given(q_and_masks(), st.sampled_from([bool, np.int8, np.int64, np.uint8, np.float32]))
def test_a_valid_mask_of_any_numeric_type_is_taken_as_it_is(
    qm: tuple[np.ndarray, np.ndarray], dtype: type
) -> None:
    _, mask = qm
    allowed = action_mask(mask.astype(dtype), mask.shape, ("n_agents", "n_actions"))
    assert allowed.dtype == torch.bool and np.array_equal(allowed.numpy(), mask == 1)


@pytest.mark.parametrize(
    ("avail", "said"),
    [
        (np.zeros((2, 3)), "avail: agent 0 has no available action"),
        (np.array([[1, 0, 0], [0, 0, 0]]), "avail: agent 1 has no available action"),
        (np.full((2, 3), np.nan), "avail must hold 0 or 1 .*got nan"),
        (-np.ones((2, 3), np.int8), "avail must hold 0 or 1 .*got -1"),
        (np.array([[1, 2, 0], [1, 0, 0]]), "avail must hold 0 or 1 .*got 2"),
        (np.full((2, 3), 0.5), "got 0.5"),
        (np.ones((1, 3)), r"avail must be a 0/1 mask of shape \[n_agents=2, n_actions=3\], "
                          r"got an array of shape \[1, 3\]"),
        (np.ones(3), r"got an array of shape \[3\]"),
        (np.ones((2, 4)), r"got an array of shape \[2, 4\]"),
        (None, "got NoneType None"),
        ([[1, 0, 0], [1, 0]], "got list"),
        (np.array([["1", "0", "0"]] * 2), r"got an array of shape \[2, 3\] \(<U1\)"),
    ],
)  # fmt: skip
def test_a_mask_that_is_not_0_1_of_the_shape_or_leaves_no_action_is_refused(
    avail: object, said: str
) -> None:
    """An all-zero, NaN or -1 mask made greedy acting pick action 0, unavailable."""
    with pytest.raises(PolicyInputError, match=said):
        action_mask(avail, (2, 3), ("n_agents", "n_actions"))


def test_a_mask_refusal_names_the_arena_of_the_agent() -> None:
    avail = np.ones((2, 2, 3), np.int8)
    avail[1, 0] = 0
    with pytest.raises(PolicyInputError, match="agent 0 in arena 7 has no available action"):
        action_mask(avail, (2, 2, 3), ("len(arenas)", "n_agents", "n_actions"), [4, 7])


@pytest.mark.parametrize(
    ("obs", "said"),
    [
        (np.zeros((2, 4)), r"obs must have shape \[n_agents=2, obs_dim=5\], got an array of "
                           r"shape \[2, 4\]"),
        (np.zeros(5), r"got an array of shape \[5\]"),
        (np.full((2, 5), np.inf), "obs must be finite numbers"),
        (np.full((2, 5), np.nan), "obs must be finite numbers"),
        ([["a"] * 5] * 2, r"obs must be numbers of shape \[n_agents=2, obs_dim=5\], got list"),
        (None, "got NoneType None"),
    ],
)  # fmt: skip
def test_observations_of_another_shape_or_not_finite_are_refused(obs: object, said: str) -> None:
    with pytest.raises(PolicyInputError, match=said):
        observations(obs, (2, 5), ("n_agents", "obs_dim"))
    good = np.ones((2, 5), np.float32)
    assert observations(good, (2, 5), ("n_agents", "obs_dim")) is good  # no copy


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


@pytest.mark.parametrize("network", [RNNAgent, MLPAgent])
def test_the_points_head_has_its_first_forms_values_and_gradients(
    network: type[RNNAgent | MLPAgent], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The in-place points head (the learner's hot path) and the form it replaced
    (:func:`score_points_sum`) give the same Q-values and the same gradients of every
    parameter and of the input."""
    index = torch.tensor([[0, 1, 5], [2, 3, 5], [4, 0, 6], [1, 2, 6]])  # 4 actions, 3 columns

    def run(form: object) -> tuple[torch.Tensor, list[torch.Tensor]]:
        monkeypatch.setattr(_QNetwork, "_score_points", form)
        torch.manual_seed(0)
        agent = network(9, 4, 16, action_index=index, head_hidden=8)
        x = torch.randn(5, 6, 9, requires_grad=True)
        q, _ = agent(x, agent.initial_hidden(5))
        (q * torch.linspace(-1, 1, q.numel()).view_as(q)).sum().backward()
        assert x.grad is not None
        return q.detach(), [x.grad, *(p.grad for p in agent.parameters() if p.grad is not None)]

    fast_q, fast_grads = run(_QNetwork._score_points)
    first_q, first_grads = run(score_points_sum)
    assert torch.allclose(fast_q, first_q, rtol=1e-5, atol=1e-6)
    assert len(fast_grads) == len(first_grads) == 1 + len(list(network(9, 4, 16).parameters())) + 4
    for a, b in zip(fast_grads, first_grads, strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6)
