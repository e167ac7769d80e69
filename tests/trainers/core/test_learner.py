"""The Q-learning core: it learns a known value, handles dead agents, refreshes targets."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch

from neuronsmae.trainers.core.buffer import EpisodeReplayBuffer
from neuronsmae.trainers.core.learner import EnvSpec, QLearner, agent_spec, lambda_returns

from ..conftest import ACTIONS, LIMIT, N_AGENTS, OBS, STATE, make_episode


def _learner(mixer: str, **kw: object) -> QLearner:
    env = EnvSpec(N_AGENTS, ACTIONS, OBS, STATE, LIMIT)
    args = {
        "lr": 5e-3,
        "gamma": 0.9,
        "grad_clip": 10.0,
        "target_update_interval": 5,
        "double_q": True,
        "mixer_embed": 8,
        "hypernet_hidden": 8,
    } | kw
    return QLearner(env, agent_spec(env, 16, True, True), mixer, **args)  # type: ignore[arg-type]


@pytest.mark.parametrize("mixer", ["none", "vdn", "qmix"])
def test_learns_one_step_reward(mixer: str) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    buf = EpisodeReplayBuffer(32, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(32):
        ep = make_episode(1, rng, dead_from=None)
        ep.rewards[:] = 2.0
        buf.add(ep)
    learner = _learner(mixer)
    for _ in range(300):
        stats = learner.train(buf.sample(32, rng))
    assert stats["loss"] < 0.05
    assert stats["q_taken"] == pytest.approx(2.0, abs=0.2)
    assert learner.updates == 300


def test_target_refresh_interval() -> None:
    rng = np.random.default_rng(1)
    buf = EpisodeReplayBuffer(8, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(8):
        buf.add(make_episode(LIMIT, rng, dead_from=3))
    learner = _learner("qmix", target_update_interval=3)
    for k in range(1, 7):
        learner.train(buf.sample(4, rng))
        same = all(
            torch.equal(a, b)
            for a, b in zip(
                learner.agent.state_dict().values(),
                learner.target_agent.state_dict().values(),
                strict=True,
            )
        )
        assert same == (k % 3 == 0)


@pytest.mark.parametrize("mixer", ["none", "vdn", "qmix"])
def test_destroyed_agent_does_not_affect_the_loss(mixer: str) -> None:
    rng = np.random.default_rng(2)
    buf = EpisodeReplayBuffer(1, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    buf.add(make_episode(LIMIT, rng, dead_from=0))  # agent 1 destroyed throughout
    batch = buf.sample(1, rng)
    losses = []
    for scale in (1.0, 100.0):
        torch.manual_seed(0)
        learner = _learner(mixer)
        batch.obs[:, :, 1] = scale  # agent 1's input changes its Q, but it is masked out
        losses.append(learner.train(batch)["loss"])
    assert losses[0] == pytest.approx(losses[1], rel=1e-6)


def test_state_dict_round_trip() -> None:
    """A learner restored from another's state (networks, targets, optimiser, count) after
    a few updates takes the next update exactly as the original does."""
    rng = np.random.default_rng(3)
    buf = EpisodeReplayBuffer(8, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(8):
        buf.add(make_episode(LIMIT, rng, dead_from=3))
    torch.manual_seed(0)
    a = _learner("qmix", target_update_interval=2)
    for _ in range(3):  # targets refreshed once, optimiser moments non-zero
        a.train(buf.sample(4, rng))
    torch.manual_seed(1)
    b = _learner("qmix", target_update_interval=2)  # other initial weights
    saved = io.BytesIO()  # as a checkpoint carries it: saved, then loaded weights-only
    torch.save(a.state_dict(), saved)
    saved.seek(0)
    b.load_state_dict(torch.load(saved, weights_only=True))
    assert b.updates == 3
    batch = buf.sample(4, rng)
    assert a.train(batch)["loss"] == b.train(batch)["loss"]
    for name in ("agent", "mixer", "target_agent", "target_mixer"):
        for x, y in zip(getattr(a, name).parameters(), getattr(b, name).parameters(),
                        strict=True):  # fmt: skip
            assert torch.equal(x, y), name


def test_lambda_returns_by_hand() -> None:
    r = torch.tensor([[1.0, 2.0, 3.0]]).unsqueeze(-1)
    d = torch.tensor([[0.0, 0.0, 1.0]]).unsqueeze(-1)
    v = torch.tensor([[10.0, 20.0, 99.0]]).unsqueeze(-1)  # values after steps 0, 1, 2
    g, lam = 0.5, 0.5
    one = lambda_returns(r, d, v, g, 0.0).flatten().tolist()
    assert one == [1 + g * 10, 2 + g * 20, 3.0]
    g2 = 3.0
    g1 = 2 + g * ((1 - lam) * 20 + lam * g2)
    g0 = 1 + g * ((1 - lam) * 10 + lam * g1)
    assert lambda_returns(r, d, v, g, lam).flatten().tolist() == pytest.approx([g0, g1, g2])


@pytest.mark.parametrize("mixer", ["none", "vdn"])
def test_a_destroyed_robot_s_own_returns_end_at_its_destruction_for_iql(
    mixer: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """IQL cut a dead robot's one-step bootstrap but not its λ-return, which went on adding
    the team's later rewards (a target of 19.6 where 0 was meant, at λ = 1)."""
    import neuronsmae.trainers.core.learner as learner_module

    seen: list[torch.Tensor] = []
    real = learner_module.lambda_returns

    def spy(r: torch.Tensor, d: torch.Tensor, *rest: object) -> torch.Tensor:
        seen.append(d.clone())
        return real(r, d, *rest)  # type: ignore[arg-type]

    monkeypatch.setattr(learner_module, "lambda_returns", spy)
    rng = np.random.default_rng(4)
    buf = EpisodeReplayBuffer(1, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    ep = make_episode(3, rng, dead_from=1)  # agent 1 acts at step 0, then is destroyed
    ep.rewards[:] = [0.0, 0.0, 20.0]
    buf.add(ep)
    _learner(mixer, td_lambda=1.0).train(buf.sample(1, rng))
    ended = seen[0][0, :3]
    if mixer == "none":  # per robot: agent 1's episode ends at step 0, agent 0's at step 2
        assert ended.tolist() == [[0.0, 1.0], [0.0, 1.0], [1.0, 1.0]]
    else:  # the team's return: the team's episode goes on
        assert ended.tolist() == [[0.0], [0.0], [1.0]]
    r = torch.tensor([[0.0, 0.0, 20.0]]).unsqueeze(-1)
    v = torch.full((1, 3, 2), 5.0)
    g = lambda_returns(r, seen[0][:, :3], v, 0.9, 1.0) if mixer == "none" else None
    if g is not None:
        assert g[0, 0, 1] == 0.0  # nothing after its destruction reaches the dead robot
        assert g[0, 0, 0] == pytest.approx(0.9 * 0.9 * 20.0)


# --- the faster step: the same mathematics -------------------------------------------------
@pytest.mark.parametrize("lam", [0.0, 0.3, 0.6, 1.0])
@pytest.mark.parametrize("k", [1, 2])
def test_the_tensor_lambda_returns_equal_the_recursion(lam: float, k: int) -> None:
    from neuronsmae.trainers.core.learner import lambda_returns_loop

    g = torch.Generator().manual_seed(int(10 * lam) + k)
    for steps in (1, 2, 3, 7, 50):
        rewards = torch.randn(6, steps, 1, generator=g)
        ended = (torch.rand(6, steps, 1, generator=g) < 0.2).float()
        values = torch.randn(6, steps, k, generator=g)
        fast = lambda_returns(rewards, ended, values, 0.99, lam)
        slow = lambda_returns_loop(rewards, ended, values, 0.99, lam)
        assert torch.allclose(fast, slow, atol=1e-5), (steps, (fast - slow).abs().max())


@pytest.mark.parametrize("mixer", ["none", "vdn", "qmix"])
def test_an_update_has_the_loss_and_gradients_of_the_recursive_targets(
    mixer: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Today's step (the λ-return loop) and the faster one give the same loss and gradients
    on the same batch from the same weights."""
    from neuronsmae.trainers.core import learner as learner_module

    rng = np.random.default_rng(4)
    buf = EpisodeReplayBuffer(8, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(8):
        buf.add(make_episode(LIMIT, rng, dead_from=3))
    batch = buf.sample(8, rng)

    def one_update(returns: object) -> tuple[float, list[torch.Tensor]]:
        monkeypatch.setattr(learner_module, "lambda_returns", returns)
        torch.manual_seed(0)
        learner = _learner(mixer, td_lambda=0.6)
        stats = learner.train(batch)
        return stats["loss"], [p.grad.clone() for p in learner.params if p.grad is not None]

    fast_loss, fast_grads = one_update(learner_module.lambda_returns)
    slow_loss, slow_grads = one_update(learner_module.lambda_returns_loop)
    assert fast_loss == pytest.approx(slow_loss, rel=1e-5)
    for a, b in zip(fast_grads, slow_grads, strict=True):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-6)


def test_a_batch_packs_into_one_buffer_and_back_unchanged() -> None:
    rng = np.random.default_rng(2)
    buf = EpisodeReplayBuffer(4, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    buf.add(make_episode(4, rng, dead_from=2))
    batch = buf.sample(3, rng)
    data, layout = batch.packed()
    assert data.dtype == torch.uint8 and data.dim() == 1
    back = type(batch).unpacked(data, layout)
    for name, dtype, _ in layout:
        assert getattr(back, name).dtype == dtype
        assert torch.equal(getattr(back, name), getattr(batch, name))
    assert batch.to(torch.device("cpu")) is batch  # nothing to move on the CPU


def test_checkpoint_state_is_on_the_cpu_and_samples_are_counted() -> None:
    rng = np.random.default_rng(3)
    buf = EpisodeReplayBuffer(4, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    buf.add(make_episode(LIMIT, rng))
    learner = _learner("qmix")
    learner.train(buf.sample(2, rng))
    state = learner.state_dict()
    tensors = [*state["agent"].values(), *state["optimizer"]["state"][0].values()]
    assert all(t.device.type == "cpu" for t in tensors)
    assert learner.samples == 2 * LIMIT and state["samples"] == 2 * LIMIT
    again = _learner("qmix")
    again.load_state_dict(state)
    assert again.samples == 2 * LIMIT and again.updates == 1


def test_a_device_this_machine_lacks_is_refused_naming_what_it_has() -> None:
    from neuronsmae.trainers.core.learner import DeviceError, resolve_device

    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(DeviceError, match="valid: auto, cpu, cuda, cuda:N"):
        resolve_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(DeviceError, match=r"no CUDA device here.*valid here: auto, cpu"):
            resolve_device("cuda:0")


def test_prefetched_batches_come_in_order_from_a_background_thread() -> None:
    import threading

    from neuronsmae.trainers.core.buffer import prefetched

    made: list[str] = []

    def make() -> int:
        made.append(threading.current_thread().name)
        return len(made)

    assert list(prefetched(make, 5)) == [1, 2, 3, 4, 5]
    assert all(name.startswith("prefetch") for name in made)
    assert list(prefetched(make, 0)) == []
    made.clear()  # inline: the same calls in the same order, in the caller's thread
    assert list(prefetched(make, 3, background=False)) == [1, 2, 3]
    assert made == [threading.current_thread().name] * 3


def test_batches_are_made_in_the_background_only_where_a_core_is_left_for_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import os

    from neuronsmae.trainers.core import buffer

    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 1)
    assert buffer.prefetch_pays("auto", cpu)  # one intra-op thread on two cores
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    assert not buffer.prefetch_pays("auto", cpu)  # the update's threads fill both cores
    assert buffer.prefetch_pays("auto", cuda)  # the CPU waits for the GPU anyway
    assert buffer.prefetch_pays("on", cpu) and not buffer.prefetch_pays("off", cuda)
