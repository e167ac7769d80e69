"""A checkpoint as a team policy over a vector of arenas (the ``neuronsmae.policies`` entry
point and the worker's opponents): what it is given is checked, and a refused call leaves
every arena's recurrent state as it was."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.policies import load_team_policy
from neuronsmae.trainers.core.agent import PolicyInputError
from neuronsmae.trainers.core.checkpoint import CheckpointError
from neuronsmae.trainers.play.policies import CheckpointPolicy, load
from tests.trainers.checkpoints import make_checkpoint

K, N, D, A = 3, 2, 37, 8
"""Arenas, agents, observation width and actions of the default 2 v 2 task."""


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_checkpoint(tmp_path_factory.mktemp("ckpt") / "a.pt", 1)


@pytest.fixture
def policy(checkpoint: Path) -> CheckpointPolicy:
    team = load(str(checkpoint))
    assert isinstance(team, CheckpointPolicy)
    team.start(K, N)
    return team


def _inputs(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-1, 1, (m, N, D)).astype(np.float32), np.ones((m, N, A), np.int8)


def _state(policy: CheckpointPolicy) -> tuple[torch.Tensor, torch.Tensor]:
    assert policy.team is not None
    return policy.team.hidden.clone(), policy.team.last.clone()


def test_a_good_call_acts_within_the_masks(policy: CheckpointPolicy) -> None:
    obs, avail = _inputs(2)
    avail[:, :, :] = 0
    avail[0, :, 3] = avail[1, :, 5] = 1
    assert policy.act(obs, avail, [2, 0]).tolist() == [[3, 3], [5, 5]]
    assert policy.act(obs[:0], avail[:0], []).shape == (0, N)


def _bad_calls() -> list[tuple[str, Any, Any, Any, str]]:
    obs, avail = _inputs(2)
    zero = avail.copy()
    zero[1, 1] = 0
    return [
        ("width-1", obs[..., :-1], avail, [0, 1], r"obs must have shape \[len\(arenas\)=2, "
         r"n_agents=2, obs_dim=37\], got an array of shape \[2, 2, 36\]"),
        ("width+1", np.concatenate([obs, obs[..., :1]], -1), avail, [0, 1], "obs_dim=37"),
        ("3 agents", np.concatenate([obs, obs[:, :1]], 1), avail, [0, 1], "n_agents=2"),
        ("one arena's obs", obs[0], avail[0], [0], r"obs must have shape \[len\(arenas\)=1"),
        ("rows != arenas", obs, avail, [0], r"len\(arenas\)=1.*got an array of shape \[2, 2"),
        ("NaN obs", np.full_like(obs, np.nan), avail, [0, 1], "obs must be finite numbers"),
        ("text obs", [["x"] * D] * N, avail, [0, 1], "obs must be numbers of shape"),
        ("mask width-1", obs, avail[..., :-1], [0, 1], r"avail must be a 0/1 mask of shape "
         r"\[len\(arenas\)=2, n_agents=2, n_actions=8\], got an array of shape \[2, 2, 7\]"),
        ("mask width+1", obs, np.ones((2, N, A + 1)), [0, 1], "n_actions=8"),
        ("one mask row", obs, avail[:, :1], [0, 1], r"got an array of shape \[2, 1, 8\]"),
        ("mask None", obs, None, [0, 1], "avail must be a 0/1 mask.*got NoneType None"),
        ("mask -1", obs, -np.ones_like(avail), [0, 1], "avail must hold 0 or 1.*got -1"),
        ("mask NaN", obs, np.full(avail.shape, np.nan), [0, 1], "got nan"),
        ("no action", obs, zero, [2, 0], "agent 1 in arena 0 has no available action"),
        ("arena 5", obs, avail, [0, 5], r"arenas must be in \[0, 2\].*got \[0, 5\]"),
        ("arena -1", obs, avail, [0, -1], r"arenas must be in \[0, 2\].*got \[0, -1\]"),
        ("twice", obs, avail, [1, 1], r"arenas names an arena twice: \[1, 1\]"),
        ("float arenas", obs, avail, [0.0, 1.0], "arenas must be a sequence of arena indices"),
        ("2-D arenas", obs, avail, [[0, 1]], "arenas must be a sequence of arena indices"),
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("obs", "avail", "arenas", "said"),
    [case[1:] for case in _bad_calls()],
    ids=[case[0] for case in _bad_calls()],
)
def test_a_bad_call_is_refused_and_changes_no_arena(
    policy: CheckpointPolicy, obs: Any, avail: Any, arenas: Any, said: str
) -> None:
    """Each was a torch error (mat1 and mat2 shapes), an IndexError, or a silent wrong
    answer: zeros for a mask allowing nothing, arena -1 read as arena 2."""
    good_obs, good_avail = _inputs(K, 1)
    policy.act(good_obs, good_avail, [0, 1, 2])  # some state to keep
    before = _state(policy)
    with pytest.raises(PolicyInputError, match=said):
        policy.act(obs, avail, arenas)
    after = _state(policy)
    assert torch.equal(before[0], after[0]) and torch.equal(before[1], after[1])


def test_reset_checks_its_arenas(policy: CheckpointPolicy) -> None:
    policy.act(*_inputs(K), [0, 1, 2])
    before = _state(policy)
    for arenas in ([3], [-1], [0.5]):
        with pytest.raises(PolicyInputError, match=r"arenas must .*\[0, 2\]"):
            policy.reset(arenas)
    assert torch.equal(_state(policy)[0], before[0])
    policy.reset(np.array([1]))
    hidden, last = _state(policy)
    assert (hidden[1] == 0).all() and (last[1] == -1).all() and (hidden[0] != 0).any()


@pytest.mark.parametrize(
    ("num_envs", "n_agents", "error", "said"),
    [
        (2, 3, InvalidOptionError, r"n_agents=3: .*a\.pt holds agents of a team of 2"),
        (2, 1, InvalidOptionError, "n_agents=1: .*drives teams of 2 robots only"),
        (0, 2, InvalidOptionError, "num_envs must be an integer >= 1, got 0"),
        (-1, 2, InvalidOptionError, "num_envs must be an integer >= 1, got -1"),
        (2.0, 2, InvalidOptionError, "num_envs must be an integer >= 1, got 2.0"),
        (2, 2.0, InvalidOptionError, "n_agents must be an integer >= 1, got 2.0"),
    ],
)
def test_start_checks_the_team_against_the_checkpoint(
    checkpoint: Path, num_envs: Any, n_agents: Any, error: type[Exception], said: str
) -> None:
    """start(2, 3) was accepted and failed at the first act with a torch shape error;
    start(0, 2) was a torch reshape error."""
    team = CheckpointPolicy(checkpoint)
    with pytest.raises(error, match=said):
        team.start(num_envs, n_agents)
    team.start(np.int64(1), np.int64(2))
    assert team.act(*_inputs(1), np.array([0])).shape == (1, N)


def test_a_side_that_is_no_text_is_refused_listing_the_valid_sides(checkpoint: Path) -> None:
    with pytest.raises(InvalidOptionError, match=r"--blue 5 \(int\) is neither a bot level "
                       r"\(easy, 0\) nor a policy's text"):  # fmt: skip
        load_team_policy(5, "--blue", ["easy", "0"])  # type: ignore[arg-type]
    assert isinstance(load_team_policy(checkpoint, "--blue", ["easy"]), CheckpointPolicy)


def test_a_checkpoint_whose_weights_do_not_fit_is_refused_as_it_loads(
    checkpoint: Path, tmp_path: Path
) -> None:
    """3 v 3 weights under a 2 v 2 agent_spec loaded, and failed at the first act."""
    three = torch.load(make_checkpoint(tmp_path / "3v3.pt", 2, n_blue=3, n_red=3),
                       weights_only=True)  # fmt: skip
    mixed = {**torch.load(checkpoint, weights_only=True), "learner": three["learner"]}
    torch.save(mixed, tmp_path / "mixed.pt")
    with pytest.raises(CheckpointError, match=r"mixed\.pt: its agent weights do not fit its "
                       r"agent_spec \(fc1\.weight is \[16, 151\], not \[16, 91\]"):  # fmt: skip
        load(str(tmp_path / "mixed.pt"))
