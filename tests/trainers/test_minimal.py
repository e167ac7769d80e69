"""The reference learner runs end to end: finite losses, and the networks learn."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from neuronsmae.server import Arena
from neuronsmae.trainers.minimal import Args, Networks, collate, parse_args, play, train

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("alg", ["vdn", "qmix"])
def test_a_few_episodes_train_the_networks(alg: str) -> None:
    args = Args(alg=alg, episodes=5, batch_size=2, target_every=2, hidden=16, eval_episodes=2)
    arena = Arena(seed=0, action_space="abstract")
    try:
        torch.manual_seed(args.seed)  # what train() starts from
        before = Networks(arena.get_env_info(), args).state_dict()
        result = train(args, arena)
    finally:
        arena.close()
    losses = result["losses"]
    assert len(losses) == 4 and np.isfinite(losses).all()  # an update from the 2nd episode on
    after = result["networks"].state_dict()
    assert set(after) == set(before)
    changed = [k for k in before if not torch.equal(before[k], after[k])]
    assert any(k.startswith("agent.") for k in changed)
    assert any(k.startswith("target_agent.") for k in changed)  # refreshed every 2 updates
    assert (alg == "qmix") == any(k.startswith("mixer.") for k in changed)
    assert 0.0 <= result["win_rate"] <= 1.0


def test_episodes_pad_to_the_longest_with_masks() -> None:
    arena = Arena(seed=0, action_space="abstract")
    try:
        info = arena.get_env_info()
        nets = Networks(info, Args(hidden=8))
        generator = torch.Generator().manual_seed(0)
        episode = play(arena, nets.agent, info, "easy", 3, 1.0, generator)
    finally:
        arena.close()
    short = {k: v[:3] if k != "winner" else v for k, v in episode.items()}
    short = {**short, **{k: episode[k][:2] for k in ("actions", "reward")}}
    batch = collate([episode, short])
    t = len(episode["reward"])
    assert batch["obs"].shape == (2, t + 1, 2, info["obs_shape"])
    assert batch["filled"][0].sum() == t and batch["filled"][1].tolist() == [1, 1] + [0] * (t - 2)
    assert bool((batch["avail"][1, 3:] == 1).all())  # padding allows every action


def test_the_command_line_reads_every_setting() -> None:
    args = parse_args(["--alg", "qmix", "--episodes", "7", "--eps-end", "0.1"])
    assert (args.alg, args.episodes, args.eps_end) == ("qmix", 7, 0.1)
    with pytest.raises(ValueError, match="alg must be vdn or qmix, got 'mappo'"):
        train(Args(alg="mappo"))


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--alg", "mappo"], "alg must be vdn or qmix, got 'mappo'"),
        (["--level", "expert"], "level must be one of 0, 1, easy, middle, hard"),
        (["--lr", "nan"], "lr must be a finite number > 0, got nan"),
        (["--gamma", "2", "--eps-start", "5"], "gamma must be in [0, 1], got 2.0; eps_start"),
        (["--batch-size", "0"], "batch_size must be an integer ≥ 1, got 0"),
        (["--buffer-size", "4"], "buffer_size must be ≥ batch_size, got 4"),
        (["--seed", "-1"], "seed must be in [0, 2³²−1], got -1"),
        (["--episodes", "0"], "episodes must be an integer ≥ 1, got 0"),
    ],
)
def test_a_setting_outside_its_range_is_a_usage_error(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """These were tracebacks from torch or numpy, or ran silently (0 episodes, γ = 2)."""
    with pytest.raises(SystemExit) as exc:
        parse_args(argv)
    assert exc.value.code == 2
    assert said in capsys.readouterr().err


def test_the_released_levels_play_as_numbers() -> None:
    """``--level 0`` reached reset as the string "0", which the arena refuses."""
    result = train(parse_args(["--level", "0", "--episodes", "1", "--eval-episodes", "1"]))
    assert 0.0 <= result["win_rate"] <= 1.0


def test_training_starts_stay_below_the_held_out_seeds(monkeypatch: pytest.MonkeyPatch) -> None:
    from neuronsmae.trainers import minimal

    seeds: list[int] = []
    real = minimal.play

    def spy(env, agent, info, level, seed, *rest):  # type: ignore[no-untyped-def]
        seeds.append(seed)
        return real(env, agent, info, level, seed, *rest)

    monkeypatch.setattr(minimal, "play", spy)
    args = Args(seed=20_000, episodes=2, batch_size=2, hidden=16, eval_episodes=1)
    arena = Arena(seed=0, action_space="abstract")
    try:
        train(args, arena)  # seed * 100_003 passed 10⁹ for seeds ≥ 10,000: held-out starts
    finally:
        arena.close()
    assert all(s < minimal.EVAL_SEED for s in seeds[:2]) and seeds[2] == minimal.EVAL_SEED
