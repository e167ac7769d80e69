"""``--preset paper`` is the authors' released training code, fact by fact
(github:DRL-CASIA/NeuronsMAE at 6026fdf; the preset's docstring names each file).

Each test pins one fact of docs/reference.md's "Their training as released": the MLP's
shape, the transition replay, the update count per iteration as the replay fills, the
target cadence in iterations, ε per worker, all-ones masks, the mixer's state, IQL's
targets, the win rule and the evaluation contexts. The released loss is written out here
on its own (as policy/vdn.py, qmix.py and iql.py compute it) and compared with the one
Q-learner's on fixed batches.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch.nn import functional as F

from neuronsmae.trainers.core.agent import MLPAgent
from neuronsmae.trainers.core.buffer import TransitionReplayBuffer
from neuronsmae.trainers.core.learner import EnvSpec, QLearner, agent_spec
from neuronsmae.trainers.play.evaluate import summarize
from neuronsmae.trainers.run.config import ConfigError, make_config, preset

from ..conftest import ACTIONS, LIMIT, N_AGENTS, OBS, STATE, make_episode

PAPER = make_config(preset("paper"))


def test_the_agent_is_the_released_mlp_on_the_observation_alone() -> None:
    lc = PAPER.learner
    assert (lc.agent_net, lc.agent_hidden, lc.features, lc.head) == ("mlp", 128, "raw", "flat")
    assert not lc.last_action_input and not lc.agent_id_input
    env = EnvSpec(2, 8, 37, 37, 50)
    spec = agent_spec(env, 128, False, False, network="mlp")
    net = spec.build()
    assert isinstance(net, MLPAgent) and spec.input_dim == 37  # the observation alone
    shapes = [tuple(p.shape) for p in net.parameters()]
    assert shapes == [(128, 37), (128,), (128, 128), (128,), (8, 128), (8,)]
    x = torch.randn(5, 3, 37)
    q, _ = net(x, net.initial_hidden(5))
    by_hand = net.fc2(F.relu(net.fc_mid(F.relu(net.fc1(x)))))
    assert torch.allclose(q, by_hand)
    q_one, _ = net(x[:, 1:2], net.initial_hidden(5))  # no memory: a step is a step
    assert torch.allclose(q_one, q[:, 1:2])


def test_the_replay_holds_200000_transitions_and_batches_of_2000() -> None:
    lc = PAPER.learner
    assert (lc.replay, lc.buffer_size, lc.batch_size, lc.learning_starts) == (
        "transitions", 200_000, 2000, 0,
    )  # fmt: skip
    rng = np.random.default_rng(0)
    buf = TransitionReplayBuffer(10, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    ep = make_episode(4, rng)
    buf.add(ep)
    assert len(buf) == 4 and buf.added == 4
    batch = buf.sample(2000, rng)  # all that are stored while fewer
    assert batch.obs.shape == (4, 2, N_AGENTS, OBS) and batch.actions.shape == (4, 1, N_AGENTS)
    assert batch.filled.tolist() == [[1.0]] * 4
    for i in range(4):  # each row is one decision (o_t, u_t, r_t, o_t+1, done_t)
        t = int(np.flatnonzero((ep.obs[:-1] == batch.obs[i, 0].numpy()).all(axis=(1, 2)))[0])
        assert np.array_equal(batch.obs[i, 1].numpy(), ep.obs[t + 1])
        assert batch.actions[i, 0].tolist() == ep.actions[t].tolist()
        assert float(batch.rewards[i, 0]) == pytest.approx(float(ep.rewards[t]))
        assert float(batch.terminated[i, 0]) == (t == 3)
    buf.add(make_episode(LIMIT, rng))
    buf.add(make_episode(LIMIT, rng))
    assert len(buf) == 10 and buf.added == 16  # a ring: the oldest overwritten
    draws = buf.sample(6, np.random.default_rng(3))
    assert draws.obs.shape[0] == 6


def test_updates_per_iteration_grow_with_the_stored_transitions() -> None:
    """max(20, 2·⌊stored / 2,000⌋): 20 at first, 200 once the 200,000 are stored."""
    lc = PAPER.learner
    stored = [1, 1000, 2000, 19_999, 20_000, 21_999, 100_000, 199_999, 200_000]
    expected = [20, 20, 20, 20, 20, 20, 100, 198, 200]
    assert [lc.updates_in_round(n) for n in stored] == expected
    # A run's 1,500 iterations as its buffer fills at 50 decisions an episode: 280,200.
    per_iteration, total, n = 20 * 50, 0, 0
    for _ in range(1500):
        n = min(n + per_iteration, lc.buffer_size)
        total += lc.updates_in_round(n)
    assert 270_000 < total < 290_000
    assert make_config().learner.updates_in_round(10**6) == 2  # the defaults: fixed


def test_targets_are_copied_at_the_first_update_of_every_fifth_iteration() -> None:
    lc = PAPER.learner
    assert (lc.target_update_interval, lc.target_update_unit) == (5, "rounds")
    assert [r for r in range(21) if lc.refreshes_targets(r)] == [0, 5, 10, 15, 20]
    assert not lc.double_q and lc.td_lambda == 0.0  # one-step targets, max over actions
    assert not make_config().learner.refreshes_targets(0)  # the defaults count updates


def test_epsilon_steps_per_iteration_as_on_each_released_worker() -> None:
    """Each of the 20 workers anneals 0.2 → 0.05 over its own 600 episodes, stepping before
    each: iteration i (from 0) plays 0.2 − (i + 1)·0.00025, the 600th plays 0.05."""
    assert PAPER.learner.eps_schedule == "iterations" and PAPER.iteration_episodes == 20
    assert [PAPER.epsilon(k) for k in range(20)] == [pytest.approx(0.19975)] * 20
    assert PAPER.epsilon(20) == pytest.approx(0.1995)
    assert PAPER.epsilon(599 * 20) == pytest.approx(0.05)
    assert PAPER.epsilon(598 * 20 + 19) == pytest.approx(0.05025)
    assert min(PAPER.epsilon(k) for k in range(0, 30_000, 7)) == pytest.approx(0.05)
    with pytest.raises(ConfigError, match="needs sync=true"):
        make_config({"learner.eps_schedule": "iterations"})


def test_masks_are_all_ones_and_destroyed_robots_are_trained_as_living() -> None:
    lc = PAPER.learner
    assert (lc.action_masks, lc.mask_destroyed) == ("ones", False)
    env = EnvSpec(2, 8, 37, 37, 50)
    spec = agent_spec(env, 128, False, False, network="mlp", masked=False)
    avail = np.zeros((3, 2, 8), np.int8)
    avail[..., 0] = 1
    assert spec.mask(avail).tolist() == np.ones((3, 2, 8)).tolist()
    assert spec.mask(torch.from_numpy(avail)).all()
    masked = agent_spec(env, 128, False, False)
    assert masked.mask(avail) is avail


def test_qmix_reads_agent_0s_observation_through_one_layer_hypernetworks() -> None:
    lc = PAPER.learner
    assert (lc.mixer_state, lc.hypernet_layers, lc.mixer_embed) == ("agent0_obs", 1, 32)
    learner = _released_learner("qmix")
    mixer = learner.mixer
    assert isinstance(mixer.hyper_w1, torch.nn.Linear)
    assert isinstance(mixer.hyper_w2, torch.nn.Linear)
    assert mixer.hyper_w1.in_features == OBS  # agent 0's observation, not the state
    assert mixer.hyper_w1.out_features == N_AGENTS * 8


def test_the_loop_contexts_and_evaluation_are_the_released_ones() -> None:
    cfg = PAPER
    assert (cfg.sync, cfg.iteration_episodes, cfg.episodes, cfg.max_minutes) == (
        True, 20, 30_000, 0.0,
    )  # fmt: skip
    assert cfg.contexts == "Friction_coeff=0.5;coef=0.5"  # coef_tr, the build's μ for blue
    tests = {k: s.value() for k, s in cfg.eval.context_specs().items()}
    assert tests == {
        "main": {"Friction_coeff": 0.5, "coef": 1.5},  # coef_ts
        "coef=1.0": {"Friction_coeff": 0.5, "coef": 1.0},
    }
    e = cfg.eval
    assert (e.eval_every, e.eval_episodes, e.final_eval_episodes) == (1000, 200, 200)
    assert (e.win_rule, e.keep_best) == ("released", False)
    lc = cfg.learner
    assert (lc.lr, lc.gamma, lc.grad_clip, lc.eps_start, lc.eps_end) == (5e-4, 0.99, 10, 0.2, 0.05)


def test_the_released_win_rule_is_agent_0s_last_reward_above_13() -> None:
    rng = np.random.default_rng(0)
    eps = []
    for last, winner in [(20.5, "blue"), (13.0, "blue"), (13.01, "blue"), (-20.0, "red"),
                         (0.3, "draw")]:  # fmt: skip
        ep = make_episode(3, rng)
        ep.rewards[-1] = last
        ep.info["winner"] = winner
        eps.append(ep)
    figures = summarize(eps)
    assert figures["released_win_rate"] == pytest.approx(2 / 5)
    assert figures["win_rate"] == pytest.approx(3 / 5)  # the referee's, beside it


# --- the released loss, written out as policy/vdn.py, qmix.py and iql.py compute it ---------
def _released_learner(mixer: str) -> QLearner:
    env = EnvSpec(N_AGENTS, ACTIONS, OBS, STATE, LIMIT)
    spec = agent_spec(env, 16, False, False, network="mlp", masked=False)
    return QLearner(
        env, spec, mixer, lr=5e-4, gamma=0.99, grad_clip=10.0, target_update_interval=None,
        double_q=False, mixer_embed=8, hypernet_hidden=8, hypernet_layers=1,
        mixer_state="agent0_obs", mask_destroyed=False,
    )  # fmt: skip


def _released_loss(learner: QLearner, batch) -> torch.Tensor:
    """The released ``learn``: Q of the taken actions on o, the target network's max over
    all actions on o', r + γ·Q_tot'(1 − done), the mean squared TD error over transitions
    (and over agents for IQL, whose reward and done are repeated per agent)."""
    o, o2 = batch.obs[:, 0], batch.obs[:, 1]  # [B, n, d]
    u = batch.actions[:, 0]  # [B, n]
    r, done = batch.rewards[:, 0:1], batch.terminated[:, 0:1]  # [B, 1]
    q = learner.agent(o, learner.agent.initial_hidden(o.shape[0]))[0]  # [B, n, A]
    q_taken = q.gather(-1, u.unsqueeze(-1)).squeeze(-1)  # [B, n]
    with torch.no_grad():
        q_next = learner.target_agent(o2, learner.agent.initial_hidden(o.shape[0]))[0]
        q_next = q_next.max(-1).values  # [B, n]
    name = learner.mixer_name
    if name == "none":
        targets = r.repeat(1, N_AGENTS) + 0.99 * q_next * (1 - done.repeat(1, N_AGENTS))
        return ((q_taken - targets) ** 2).mean()
    if name == "vdn":
        tot, tot_next = q_taken.sum(1, keepdim=True), q_next.sum(1, keepdim=True)
    else:
        tot = learner.mixer(q_taken.unsqueeze(1), o[:, 0].unsqueeze(1))[:, 0]
        tot_next = learner.target_mixer(q_next.unsqueeze(1), o2[:, 0].unsqueeze(1))[:, 0]
    targets = r + 0.99 * tot_next * (1 - done)
    return ((tot - targets) ** 2).mean()


@pytest.mark.parametrize("mixer", ["none", "vdn", "qmix"])
def test_the_one_learner_computes_the_released_loss_and_gradients(mixer: str) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    buf = TransitionReplayBuffer(100, N_AGENTS, OBS, STATE, ACTIONS, LIMIT)
    for _ in range(6):  # agent 1 destroyed from step 2: the released code trains it anyway
        ep = make_episode(LIMIT, rng, dead_from=2)
        ep.avail[:] = 1  # as the workers store them with all-ones masks
        buf.add(ep)
    learner = _released_learner(mixer)
    for _ in range(3):  # targets differ from the online networks after a few updates
        learner.train(buf.sample(16, rng))
    batch = buf.sample(32, rng)
    learner.optimizer.zero_grad(set_to_none=True)
    expected = _released_loss(learner, batch)
    expected.backward()
    want = [p.grad.clone() for p in learner.params if p.grad is not None]
    learner.optimizer.zero_grad(set_to_none=True)
    stats = learner.train(batch)
    assert stats["loss"] == pytest.approx(float(expected.detach()), rel=1e-5)
    learner_grads = [p.grad for p in learner.params if p.grad is not None]
    # train() stepped the optimiser after clipping; the clipped gradient is a scaled one
    scale = min(1.0, 10.0 / float(torch.norm(torch.stack([g.norm() for g in want]))))
    for got, ref in zip(learner_grads, want, strict=True):
        assert torch.allclose(got, ref * scale, rtol=1e-4, atol=1e-6)
