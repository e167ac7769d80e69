"""Acting from checkpoints: the saved weights are what loads, and acting is greedy."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from neuronsmae.protocol.errors import InvalidContextError, InvalidOptionError
from neuronsmae.server.arena import Arena
from neuronsmae.trainers.core.agent import PolicyInputError
from neuronsmae.trainers.core.checkpoint import CheckpointError, Counters, save_checkpoint
from neuronsmae.trainers.core.learner import EnvSpec, QLearner, agent_spec
from neuronsmae.trainers.play.evaluate import GreedyPolicy, act_greedily, load_policy
from neuronsmae.trainers.run.config import TrainConfig

ENV = EnvSpec(n_agents=2, n_actions=8, obs_dim=37, state_dim=21, episode_limit=50)


def _checkpoint(path: Path, seed: int) -> QLearner:
    torch.manual_seed(seed)
    learner = QLearner(
        ENV,
        agent_spec(ENV, 16, True, True),
        "vdn",
        lr=1e-3,
        gamma=0.99,
        grad_clip=10.0,
        target_update_interval=10,
        double_q=True,
        mixer_embed=8,
        hypernet_hidden=8,
    )
    save_checkpoint(
        path,
        config=TrainConfig().to_dict(),
        env=ENV,
        spec=learner.spec,
        learner_state=learner.state_dict(),
        counters=Counters(),
        np_rng=np.random.default_rng(seed),
    )
    return learner


def test_checkpoint_hands_out_the_agents_weights(tmp_path: Path) -> None:
    learner = _checkpoint(tmp_path / "checkpoint.pt", 0)
    policy = load_policy(tmp_path)  # the run directory finds checkpoint.pt
    assert policy.spec == learner.spec
    for k, v in learner.acting_weights().items():
        assert np.array_equal(policy.weights[k], v)


def test_greedy_policy_takes_the_best_available_action_and_values_the_team(
    tmp_path: Path,
) -> None:
    _checkpoint(tmp_path / "a.pt", 10)
    policy, twin = GreedyPolicy(tmp_path / "a.pt"), GreedyPolicy(tmp_path / "a.pt")
    rng = np.random.default_rng(0)
    for _ in range(4):
        obs = list(rng.uniform(-1, 1, (2, 37)).astype(np.float32))
        avail = list((rng.random((2, 8)) < 0.6).astype(np.int8))
        for mask in avail:
            mask[rng.integers(8)] = 1
        q = twin.q_values(obs).masked_fill(torch.as_tensor(np.asarray(avail)) == 0, -np.inf)
        chosen, value = act_greedily(policy, obs, avail)
        assert chosen == q.argmax(dim=-1).tolist()
        assert value == pytest.approx(float(q.max(dim=-1).values.sum()), rel=1e-6)
        twin.chose(torch.as_tensor(chosen))
        assert policy.last is not None and policy.last.tolist() == chosen


def test_greedy_policy_plays_a_whole_episode(tmp_path: Path) -> None:
    _checkpoint(tmp_path / "a.pt", 1)
    policy = GreedyPolicy(tmp_path / "a.pt")
    arena = Arena(seed=3, action_space="abstract")
    try:
        obs, done, taken = arena.reset(seed=5), False, 0
        policy.reset()
        while not done:
            avail = arena.get_avail_actions()
            actions = policy.act(obs, avail)
            assert all(mask[a] for mask, a in zip(avail, actions, strict=True))
            obs, _, done, _ = arena.step(actions)
            taken += 1
    finally:
        arena.close()
    assert taken > 1


@pytest.mark.slow
def test_a_checkpoint_is_evaluated_on_the_task_it_trained_on(tmp_path: Path) -> None:
    from neuronsmae.trainers.play.evaluate import evaluate_checkpoint
    from tests.trainers.checkpoints import make_checkpoint

    path = make_checkpoint(tmp_path / "3v3.pt", 1, n_blue=3, n_red=3, reward="sparse")
    result = evaluate_checkpoint(path, "random", episodes=2, seed=3, envs=2)
    assert result["eval_episodes"] == 2 and result["level"] == "random"
    assert result["mean_return"] in (-1.0, 0.0, 1.0, -0.5, 0.5)  # sparse: ±1 or 0 per episode


def test_a_level_among_the_contexts_is_refused_not_overridden(tmp_path: Path) -> None:
    """The level argument replaced a ``level`` context silently: a re-test against another
    bot played the run's own."""
    from neuronsmae.protocol.errors import InvalidContextError
    from neuronsmae.trainers.play.evaluate import evaluate_checkpoint

    with pytest.raises(InvalidContextError, match="level=0 beside level='easy'"):
        evaluate_checkpoint(tmp_path / "x.pt", "easy", 1, 0, contexts={"level": 0})


@pytest.mark.parametrize("level", ["2", 2, "medium", 1.5, True])
def test_an_unknown_level_is_refused_before_anything_loads(level: object, tmp_path: Path) -> None:
    from neuronsmae.protocol.errors import InvalidContextError
    from neuronsmae.trainers.play.evaluate import evaluate_checkpoint

    with pytest.raises(InvalidContextError, match="'easy', 'middle' and 'hard'") as err:
        evaluate_checkpoint(tmp_path / "missing.pt", level, episodes=1, seed=0)  # type: ignore[arg-type]
    assert repr(level) in str(err.value)


def _bad_inputs() -> list[tuple[str, Any, Any, str]]:
    rng = np.random.default_rng(3)
    obs, avail = rng.uniform(-1, 1, (2, 37)).astype(np.float32), np.ones((2, 8), np.int8)
    one = np.zeros_like(avail)
    one[:, 3] = 1
    return [
        ("width-1", obs[:, :-1], avail,
         r"obs must have shape \[n_agents=2, obs_dim=37\], got an array of shape \[2, 36\]"),
        ("width+1", np.hstack([obs, obs[:, :1]]), avail, r"got an array of shape \[2, 38\]"),
        ("3 agents", np.vstack([obs, obs[:1]]), np.vstack([avail, avail[:1]]), "n_agents=2"),
        ("1 agent", obs[:1], avail[:1], "n_agents=2"),
        ("1-D", obs[0], one[0], r"shape \[8\]|shape \[37\]"),
        ("NaN obs", np.full_like(obs, np.nan), avail, "obs must be finite numbers"),
        ("None obs", None, avail, "obs must have shape .*got NoneType None"),
        ("no action", obs, np.zeros_like(avail), "avail: agent 0 has no available action"),
        ("NaN mask", obs, np.full((2, 8), np.nan), "avail must hold 0 or 1.*got nan"),
        ("-1 mask", obs, -np.ones((2, 8)), "avail must hold 0 or 1.*got -1"),
        ("mask width-1", obs, avail[:, :-1],
         r"avail must be a 0/1 mask of shape \[n_agents=2, n_actions=8\], got .* \[2, 7\]"),
        ("mask width+1", obs, np.ones((2, 9)), r"\[2, 9\]"),
        ("one mask row", obs, one[:1], r"got an array of shape \[1, 8\]"),
        ("1-D mask", obs, one[0], r"got an array of shape \[8\]"),
        ("None mask", obs, None, "avail must be a 0/1 mask.*got NoneType None"),
    ]  # fmt: skip


@pytest.mark.parametrize(
    ("obs", "avail", "said"),
    [case[1:] for case in _bad_inputs()],
    ids=[case[0] for case in _bad_inputs()],
)
@pytest.mark.parametrize("features", ["raw", "relative"])
def test_greedy_policy_refuses_what_does_not_fit_and_keeps_its_state(
    features: str, obs: Any, avail: Any, said: str, tmp_path: Path
) -> None:
    """Each was a torch or numpy error (mat1 and mat2 shapes cannot be multiplied, an
    IndexError) or a silent [0, 0]; the docstring promises the greedy *available* action."""
    from tests.trainers.checkpoints import make_checkpoint

    if features == "raw":  # no layout in its spec: the sizes come from the checkpoint's env
        _checkpoint(tmp_path / "a.pt", 4)
    else:
        make_checkpoint(tmp_path / "a.pt", 4)
    policy, twin = GreedyPolicy(tmp_path / "a.pt"), GreedyPolicy(tmp_path / "a.pt")
    assert policy.spec.features == features
    first = np.random.default_rng(0).uniform(-1, 1, (2, 37)).astype(np.float32)
    assert policy.act(first, np.ones((2, 8))) == twin.act(first, np.ones((2, 8)))
    with pytest.raises(PolicyInputError, match=said):
        policy.act(obs, avail)
    for mask in (np.ones((2, 8), bool), np.ones((2, 8), np.float32)):  # state as the twin's
        assert policy.act(first, mask) == twin.act(first, mask)
    assert torch.equal(policy.hidden, twin.hidden)  # type: ignore[arg-type]


def _payload(tmp_path: Path) -> dict[str, Any]:
    _checkpoint(tmp_path / "good.pt", 5)
    return torch.load(tmp_path / "good.pt", weights_only=True)


def _corrupt(good: dict[str, Any], case: str, tmp_path: Path) -> dict[str, Any]:
    spec, learner = good["agent_spec"], good["learner"]
    agent = learner["agent"]
    if case in ("3v3 weights", "3v3 layout", "input_dim 48, 2v2 layout"):
        from tests.trainers.checkpoints import make_checkpoint

        teams = 2 if case.endswith("2v2 layout") else 3
        path = make_checkpoint(tmp_path / "other.pt", 1, n_blue=teams, n_red=teams)
        other = torch.load(path, weights_only=True)
        if case == "3v3 weights":
            return {**good, "learner": other["learner"]}
        layout = other["agent_spec"]["env_info"]
        width = 48 if teams == 2 else spec["input_dim"]
        return {**good, "agent_spec": {**spec, "env_info": layout, "input_dim": width}}
    return {
        "no agent_spec": {k: v for k, v in good.items() if k != "agent_spec"},
        "no learner": {k: v for k, v in good.items() if k != "learner"},
        "agent_spec None": {**good, "agent_spec": None},
        "extra spec key": {**good, "agent_spec": {**spec, "zzz": 1}},
        "missing spec key": {**good, "agent_spec": {k: v for k, v in spec.items()
                                                     if k != "agent_id"}},
        "hidden_dim text": {**good, "agent_spec": {**spec, "hidden_dim": "16"}},
        "hidden_dim 32": {**good, "agent_spec": {**spec, "hidden_dim": 32}},
        "input_dim 48": {**good, "agent_spec": {**spec, "input_dim": 48}},
        "features bogus": {**good, "agent_spec": {**spec, "features": "bogus"}},
        "no learner.agent": {**good, "learner": {}},
        "agent not tensors": {**good, "learner": {"agent": {k: 1 for k in agent}}},
        "weight missing": {**good, "learner": {"agent": {k: v for k, v in agent.items()
                                                         if k != "fc2.bias"}}},
        "format '2'": {**good, "format": "2"},
    }[case]  # fmt: skip


@pytest.mark.parametrize(
    ("case", "said"),
    [
        ("no agent_spec", "is not a complete checkpoint: its 'agent_spec' entry must be a dict, "
                          "it has none"),
        ("no learner", "its 'learner' entry must be a dict, it has none"),
        ("agent_spec None", "its 'agent_spec' entry must be a dict, it has NoneType None"),
        ("extra spec key", r"its agent_spec has unknown key\(s\) \['zzz'\]; an agent_spec holds"),
        ("missing spec key", r"its agent_spec has no \['agent_id'\]"),
        ("hidden_dim text", "agent_spec hidden_dim='16' is a str, not int"),
        ("hidden_dim 32", r"its agent weights do not fit its agent_spec \(fc1.weight is "
                          r"\[16, 47\], not \[32, 47\]"),
        ("input_dim 48", r"fc1.weight is \[16, 47\], not \[16, 48\]"),
        ("input_dim 48, 2v2 layout", "agent_spec input_dim=48 does not fit its layout: 37 "
                                     "observation columns [+] 10 one-hot columns for 2 agents"),
        ("3v3 layout", "agent_spec n_actions=8 does not fit its layout, which has 12 actions"),
        ("features bogus", r"features='bogus', head='flat'; valid: features in \['raw'"),
        ("no learner.agent", r"needs the agent's weights \('agent': a dict of name to tensor\), "
                             "got none"),
        ("agent not tensors", "needs the agent's weights .*got dict"),
        ("weight missing", "fc2.bias is missing"),
        ("3v3 weights", r"fc1.weight is \[16, 151\], not \[16, 47\]"),
        ("format '2'", "has checkpoint format '2', not 2"),
    ],
)  # fmt: skip
def test_a_checkpoint_with_a_bad_part_is_refused_as_it_loads(
    case: str, said: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each was a KeyError or TypeError from evaluate.py or AgentSpec, or loaded and failed
    later with torch's 'size mismatch' (the 3 v 3 weights, the changed hidden_dim)."""
    from neuronsmae.trainers.play import evaluate
    from neuronsmae.trainers.play.policies import load

    path = tmp_path / "bad.pt"
    torch.save(_corrupt(_payload(tmp_path), case, tmp_path), path)
    monkeypatch.setattr(evaluate, "RolloutWorker", lambda *a, **k: pytest.fail("played"))
    for loader in (load_policy, GreedyPolicy, lambda p: load(str(p)),
                   lambda p: evaluate.evaluate_checkpoint(p, "easy", 1, 0)):  # fmt: skip
        with pytest.raises(CheckpointError, match=re.escape(str(path)) + ".*" + said):
            loader(path)


def test_a_checkpoint_without_its_run_config_is_refused_before_playing(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from neuronsmae.trainers.play import evaluate

    good = _payload(tmp_path)
    monkeypatch.setattr(evaluate, "RolloutWorker", lambda *a, **k: pytest.fail("played"))
    for bad, said in (
        ({**good, "config": None}, "its config's arena options cannot be read"),
        ({**good, "config": {"arena": {"n_blue": 9}}}, r"options .*: arena.n_blue must be in"),
        ({k: v for k, v in good.items() if k != "counters"}, "its counters' episodes cannot"),
    ):
        torch.save(bad, tmp_path / "bad.pt")
        with pytest.raises(CheckpointError, match=r"bad\.pt: .*" + said):
            evaluate.evaluate_checkpoint(tmp_path / "bad.pt", "easy", 1, 0)


@pytest.mark.parametrize(
    ("kwargs", "error", "said"),
    [
        ({"episodes": 2.5}, InvalidOptionError, "episodes must be an integer >= 1, got 2.5"),
        ({"episodes": 9.5}, InvalidOptionError, "episodes must be an integer >= 1, got 9.5"),
        ({"episodes": "2"}, InvalidOptionError, "episodes must be an integer >= 1, got '2'"),
        ({"episodes": 0}, InvalidOptionError, "episodes must be an integer >= 1, got 0"),
        ({"envs": 100, "episodes": 65}, InvalidOptionError,
         r"envs must be an integer \[1, 64\], got 100"),
        ({"envs": 0}, InvalidOptionError, r"envs must be an integer \[1, 64\], got 0"),
        ({"seed": 2**63 - 2, "episodes": 3, "envs": 1}, InvalidContextError,
         r"seed=9223372036854775806 with episodes=3: .* must be in \[0, 9223372036854775805\]"),
        ({"seed": -1}, InvalidContextError, r"seed -1 is out of range; valid: \[0, "),
        ({"seed": "5"}, InvalidContextError, "seed must be an integer in"),
        ({"contexts": [1, 2]}, InvalidContextError, "contexts must be a mapping .* got list"),
        ({"port": 30555}, InvalidOptionError, "port=30555 needs env='remote'"),
        ({"env": "remote", "port": 70000}, InvalidOptionError,
         r"port must be an integer \[1, 65535\], got 70000"),
        ({"env": "bogus"}, InvalidOptionError, r"env must be one of \['inprocess', 'remote'\]"),
    ],
)  # fmt: skip
def test_evaluate_checkpoint_names_a_bad_argument_before_anything_loads(
    kwargs: dict[str, Any], error: type[Exception], said: str, tmp_path: Path
) -> None:
    """Each was a TypeError deep in rollout.py, an error naming num_envs or 'arena 0', or
    (port with env='inprocess') silently ignored. The checkpoint does not exist: the
    arguments are refused before it is read."""
    from neuronsmae.trainers.play.evaluate import evaluate_checkpoint

    args: dict[str, Any] = {"episodes": 1, "seed": 0, **kwargs}
    with pytest.raises(error, match=said):
        evaluate_checkpoint(tmp_path / "missing.pt", "easy", **args)


def test_evaluate_checkpoint_takes_numpy_integers(tmp_path: Path) -> None:
    """seed=np.int64(5) was a TypeError in rollout.py (the match took it)."""
    from neuronsmae.trainers.play.evaluate import evaluate_checkpoint
    from tests.trainers.checkpoints import make_checkpoint

    path = make_checkpoint(tmp_path / "a.pt", 1)
    result = evaluate_checkpoint(path, np.int64(1), np.int64(2), np.int64(5), envs=np.int64(2))
    assert (result["eval_episodes"], result["seed"], result["level"]) == (2, 5, 1)
    assert type(result["seed"]) is int
