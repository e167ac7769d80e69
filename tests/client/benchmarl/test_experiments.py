"""BenchMARL experiments on NeuronsMAE, run to completion over private servers with a tiny
budget: MAPPO on continuous actions, QMIX on abstract actions with masks; then each
checkpoint played through the ``neuronsmae.policies`` entry point ("benchmarl"), the QMIX one
in a ``neuronsmae-match``."""

from __future__ import annotations

import json
from collections.abc import Iterator
from importlib.metadata import entry_points
from pathlib import Path

import numpy as np
import pytest

pytestmark = [
    pytest.mark.interop,
    pytest.mark.filterwarnings("ignore:PettingZoo in TorchRL is tested:UserWarning"),
    pytest.mark.filterwarnings("ignore::DeprecationWarning"),
]

pytest.importorskip("benchmarl")

from benchmarl.algorithms import MappoConfig, QmixConfig  # noqa: E402
from benchmarl.experiment import Experiment, ExperimentConfig  # noqa: E402
from benchmarl.models.mlp import MlpConfig  # noqa: E402

from neuronsmae.client.benchmarl import NeuronsMAETask  # noqa: E402
from neuronsmae.protocol.levels import LEVEL_ARGS  # noqa: E402
from neuronsmae.protocol.policies import load_team_policy  # noqa: E402
from neuronsmae.trainers.play.benchmarl import BenchMARLPolicy  # noqa: E402

FRAMES = 200
"""Frames per experiment: two batches of 100 from two environments (a private server each,
and one for evaluation)."""


def tiny(folder: Path) -> ExperimentConfig:
    """BenchMARL's default experiment cut to :data:`FRAMES` frames, one evaluation episode,
    CSV logs and a checkpoint at the end, in ``folder``."""
    config = ExperimentConfig.get_from_yaml()
    for prefix in ("on_policy", "off_policy"):
        setattr(config, f"{prefix}_collected_frames_per_batch", FRAMES // 2)
        setattr(config, f"{prefix}_n_envs_per_worker", 2)
    config.on_policy_minibatch_size, config.on_policy_n_minibatch_iters = 50, 1
    config.off_policy_n_optimizer_steps, config.off_policy_train_batch_size = 2, 32
    config.max_n_frames = FRAMES
    config.evaluation_interval, config.evaluation_episodes = FRAMES, 1
    config.loggers, config.checkpoint_at_end = ["csv"], True
    config.save_folder = str(folder)
    return config


def run(task: NeuronsMAETask, algorithm: object, folder: Path) -> Experiment:
    experiment = Experiment(
        task=task.get_from_yaml(),  # env: null, a private server per environment
        algorithm_config=algorithm,
        model_config=MlpConfig.get_from_yaml(),
        seed=0,
        config=tiny(folder),
    )
    experiment.run()
    return experiment


@pytest.fixture(scope="module")
def mappo(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Experiment]:
    yield run(NeuronsMAETask.COOP_CONTINUOUS, MappoConfig.get_from_yaml(),
              tmp_path_factory.mktemp("mappo"))  # fmt: skip


@pytest.fixture(scope="module")
def qmix(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Experiment]:
    yield run(NeuronsMAETask.COOP_ABSTRACT, QmixConfig.get_from_yaml(),
              tmp_path_factory.mktemp("qmix"))  # fmt: skip


def test_mappo_on_continuous_actions_runs_to_completion(mappo: Experiment) -> None:
    assert mappo.total_frames == FRAMES and mappo.continuous_actions
    assert (mappo.folder_name / "checkpoints" / f"checkpoint_{FRAMES}.pt").is_file()
    assert mappo.action_mask_spec is None and mappo.state_spec is not None
    # marl-eval's JSON: environment, task, algorithm, seed, then the evaluations' returns
    report = json.loads((mappo.folder_name / f"{mappo.name}.json").read_text())
    runs = report["neuronsmae"]["coop_continuous"]["mappo"]["seed_0"]
    assert all(len(step["return"]) == 1 for key, step in runs.items() if key.startswith("step_"))


def test_qmix_on_abstract_actions_with_masks_runs_to_completion(qmix: Experiment) -> None:
    assert qmix.total_frames == FRAMES and not qmix.continuous_actions
    assert qmix.action_mask_spec["blue", "action_mask"].shape == (2, 8)
    batch = qmix.replay_buffers["blue"].storage[:]  # every collected step
    taken = batch["blue", "action"]
    allowed = batch["blue", "action_mask"].gather(-1, taken.unsqueeze(-1))
    assert bool(allowed.all())  # the ε-greedy policy only picked available actions


def test_the_entry_point_loads_a_checkpoint_and_acts_deterministically(
    mappo: Experiment, qmix: Experiment
) -> None:
    assert "benchmarl" in {ep.name for ep in entry_points(group="neuronsmae.policies")}
    for experiment, continuous in ((qmix, False), (mappo, True)):
        policy = load_team_policy(str(experiment.folder_name), "--blue", LEVEL_ARGS)
        assert isinstance(policy, BenchMARLPolicy) and policy.continuous == continuous
        assert policy.options == experiment.task.config["options"]
        policy.start(3, 2)
        obs = np.random.default_rng(0).uniform(-1, 1, (3, 2, policy.env_info["obs_shape"]))
        avail = np.ones((3, 2, policy.env_info["n_actions"]), np.int8)
        avail[:, :, 0] = 0
        first = policy.act(obs, avail, [0, 1, 2])
        assert np.array_equal(first, policy.act(obs, avail, [0, 1, 2]))
        if continuous:
            assert first.shape == (3, 2, 4) and set(first[..., 3].ravel()) <= {0.0, 1.0}
        else:
            assert first.shape == (3, 2) and (first > 0).all()  # action 0 was masked


def test_a_benchmarl_checkpoint_plays_neuronsmae_match(
    qmix: Experiment, capsys: pytest.CaptureFixture[str]
) -> None:
    checkpoint = qmix.folder_name / "checkpoints" / f"checkpoint_{FRAMES}.pt"
    (match,) = entry_points(group="console_scripts", name="neuronsmae-match")
    argv = ["--blue", str(checkpoint), "--red", "easy", "--episodes", "4", "--arenas", "2",
            "--json"]  # fmt: skip
    assert match.load()(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["episodes"] == 4 and len(result["winners"]) == 4
    assert result["blue"] == str(checkpoint)
