"""Mixers on hand-made inputs, QMIX's monotonicity, and the registry's errors."""

from __future__ import annotations

import math

import pytest
import torch

from neuronsmae.trainers.core.mixers import (
    IdentityMixer,
    QMixer,
    UnknownMixerError,
    VDNMixer,
    make_mixer,
    mixer_for_algorithm,
)


def test_vdn_sums_agent_qs() -> None:
    qs = torch.tensor([[[1.0, 2.0], [-3.0, 0.5]]])  # [B=1, T=2, n=2]
    out = VDNMixer()(qs, torch.zeros(1, 2, 5))
    assert out.shape == (1, 2, 1)
    assert out.flatten().tolist() == [3.0, -2.5]


def test_identity_mixer_keeps_agents() -> None:
    qs = torch.randn(3, 4, 2)
    assert torch.equal(IdentityMixer()(qs, torch.zeros(3, 4, 7)), qs)


def _constant(linear: torch.nn.Linear, values: list[float]) -> None:
    """Make a hypernetwork's last layer output ``values`` whatever the state."""
    with torch.no_grad():
        linear.weight.zero_()
        linear.bias.copy_(torch.tensor(values))


def test_qmix_on_hand_made_weights() -> None:
    mixer = QMixer(n_agents=2, state_dim=3, embed_dim=2, hypernet_hidden=4)
    _constant(mixer.hyper_w1[-1], [1.0, 0.0, 0.0, -2.0])  # W1 = |[[1, 0], [0, -2]]|
    _constant(mixer.hyper_b1, [0.0, -10.0])
    _constant(mixer.hyper_w2[-1], [3.0, -1.0])  # w2 = |[3, -1]|
    _constant(mixer.hyper_b2[-1], [0.5])
    qs = torch.tensor([[[1.0, 2.0]]])
    # hidden = elu([1·1 + 0, 2·2 − 10]) = [1, elu(−6)]; Q_tot = 3·1 + 1·elu(−6) + 0.5
    expected = 3.0 + (math.exp(-6.0) - 1.0) + 0.5
    out = mixer(qs, torch.randn(1, 1, 3))
    assert out.shape == (1, 1, 1)
    assert out.item() == pytest.approx(expected, abs=1e-5)


@pytest.mark.parametrize("seed", range(5))
def test_qmix_is_monotonic_in_every_agent(seed: int) -> None:
    torch.manual_seed(seed)
    mixer = QMixer(n_agents=3, state_dim=6, embed_dim=8, hypernet_hidden=16)
    qs = (torch.randn(16, 5, 3) * 10).requires_grad_()
    states = torch.randn(16, 5, 6) * 3
    mixer(qs, states).sum().backward()
    assert qs.grad is not None
    assert (qs.grad >= 0).all()


def test_registry_builds_and_rejects() -> None:
    assert isinstance(make_mixer("vdn", 2, 4), VDNMixer)
    assert isinstance(make_mixer("qmix", 2, 4), QMixer)
    assert mixer_for_algorithm("iql") == "none"
    with pytest.raises(UnknownMixerError, match="valid: none, qmix, vdn"):
        make_mixer("qtran", 2, 4)
    with pytest.raises(UnknownMixerError, match="valid: iql, qmix, vdn"):
        mixer_for_algorithm("mappo")
