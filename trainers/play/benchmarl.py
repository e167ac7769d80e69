"""A trained BenchMARL experiment as a team policy: the ``neuronsmae.policies`` loader
"benchmarl".

:func:`load` takes a BenchMARL checkpoint of a NeuronsMAE task
(:mod:`neuronsmae.client.benchmarl.tasks`): a checkpoint file
(``<experiment>/checkpoints/checkpoint_<frames>.pt``, with BenchMARL's ``config.pkl`` in
``<experiment>``) or an experiment folder (its latest checkpoint). It returns a
:class:`BenchMARLPolicy`, blue's agents acting deterministically (BenchMARL's evaluation mode:
the most likely action, masked, or the mean of a continuous policy; no exploration), which
``neuronsmae-match`` and ``neuronsmae-league`` play like any other policy; given anything
else, None. The policy is rebuilt by BenchMARL itself (its ``Experiment`` from
``config.pkl``, restored from the checkpoint) around one in-process arena, so nothing is
launched. Recurrent models (GRU, LSTM) are refused.

This module imports BenchMARL only once a checkpoint is found, so the loader is harmless
where the ``interop`` extra is not installed. A BenchMARL experiment is pickles (its
``config.pkl``, and a checkpoint BenchMARL unpickles): as with BenchMARL's own
``Experiment.reload_from_file``, load only experiments you trust. (The trainers' own
checkpoints load with ``weights_only=True`` and run nothing.)
"""

from __future__ import annotations

import copy
import pickle
import re
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.errors import InvalidOptionError, MissingDependencyError
from neuronsmae.protocol.interface import count_option

CONFIG_FILE = "config.pkl"
"""BenchMARL's pickled configuration, in the experiment folder."""
CHECKPOINTS = "checkpoints"
"""The experiment folder's folder of checkpoints, ``checkpoint_<frames>.pt``."""
_CHECKPOINT = re.compile(r"checkpoint_(\d+)\.pt")


def find_checkpoint(text: str) -> Path | None:
    """The checkpoint file ``text`` names, if it names a BenchMARL experiment's: the file
    itself, or an experiment folder's latest checkpoint; None for anything else. An
    experiment folder without a checkpoint is an :class:`InvalidOptionError`."""
    path = Path(text)
    if path.is_file():
        folder = path.parent.parent
        if path.parent.name == CHECKPOINTS and (folder / CONFIG_FILE).is_file():
            return path
        return None
    if path.is_dir() and (path / CONFIG_FILE).is_file() and (path / CHECKPOINTS).is_dir():
        found = sorted(
            (int(m.group(1)), p)
            for p in (path / CHECKPOINTS).iterdir()
            if (m := _CHECKPOINT.fullmatch(p.name))
        )
        if not found:
            raise InvalidOptionError(
                f"{text}: a BenchMARL experiment folder without checkpoints; train with "
                "experiment.checkpoint_at_end=true or a checkpoint_interval"
            )
        return found[-1][1]
    return None


def load(text: str) -> BenchMARLPolicy | None:
    """The entry point: a BenchMARL checkpoint file or experiment folder, else None."""
    checkpoint = find_checkpoint(text)
    return None if checkpoint is None else BenchMARLPolicy(checkpoint)


class BenchMARLPolicy:
    """A BenchMARL checkpoint's blue agents as a
    :class:`~neuronsmae.protocol.policies.TeamPolicy` (deterministic, batched over arenas)."""

    def __init__(self, checkpoint: str | Path) -> None:
        try:
            import torch  # noqa: F401
            from benchmarl.experiment import Experiment  # noqa: F401
        except ImportError as exc:
            raise MissingDependencyError(
                f"{checkpoint} is a BenchMARL checkpoint; playing it needs BenchMARL: "
                "pip install 'neuronsmae[interop]'"
            ) from exc
        self.path = str(checkpoint)
        self.policy, self.settings, info = _restore(Path(checkpoint))
        self.options: Mapping[str, Any] = dict(self.settings.options)
        """The task's arena options (team sizes, action space, ...)."""
        self.env_info: Mapping[str, Any] | None = info
        """The ``get_env_info()`` of the team the experiment trained (blue)."""
        self.n_agents = int(info["n_agents"])
        self.continuous = info["action_space"] == "continuous"
        self.num_envs: int | None = None

    def start(self, num_envs: int, n_agents: int) -> None:
        n_agents = count_option("n_agents", n_agents, 1)
        if n_agents != self.n_agents:
            raise InvalidOptionError(
                f"n_agents={n_agents}: {self.path} holds a team of {self.n_agents} agents and "
                f"drives teams of {self.n_agents} robots only"
            )
        self.num_envs = count_option("num_envs", num_envs, 1)

    def reset(self, arenas: Sequence[int]) -> None:
        """Nothing to forget (the policy has no recurrent state); checks ``arenas``."""
        self._arenas(arenas)

    def act(self, obs: np.ndarray, avail: np.ndarray, arenas: Sequence[int]) -> np.ndarray:
        """Actions for ``arenas``: ``[m, n_agents]`` choices, or for continuous actions
        ``[m, n_agents, 4]`` rows ``(vx, vy, omega, target index)`` as the arena takes them."""
        import torch
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        from neuronsmae.client.benchmarl.tasks import GROUP

        m = len(self._arenas(arenas))
        obs, avail = np.asarray(obs), np.asarray(avail)
        want = (m, self.n_agents, int(self.env_info["obs_shape"]))  # type: ignore[index]
        if obs.shape != want or avail.shape[:2] != want[:2]:
            raise InvalidOptionError(
                f"obs must have shape {want} and avail [{m}, {self.n_agents}, n_actions] for "
                f"{m} arenas, got {obs.shape} and {avail.shape}"
            )
        group: dict[str, Any] = {"observation": torch.as_tensor(obs, dtype=torch.float32)}
        if not self.continuous:
            group["action_mask"] = torch.as_tensor(avail).bool()
        td = TensorDict({GROUP: TensorDict(group, batch_size=[m, self.n_agents])}, [m])
        with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
            action = self.policy(td).get((GROUP, "action")).cpu().numpy()
        if not self.continuous:
            return action.astype(np.int64)
        from neuronsmae.client.spaces import Layout
        from neuronsmae.protocol.env_info import EnvInfo

        return Layout(EnvInfo.from_dict(self.env_info)).joint_to_arena(action)  # type: ignore[arg-type]

    def _arenas(self, arenas: Sequence[int]) -> list[int]:
        if self.num_envs is None:
            raise RuntimeError("call start(num_envs, n_agents) before reset() or act()")
        listed = [count_option("arena", a, 0, self.num_envs - 1) for a in arenas]
        if len(set(listed)) != len(listed):
            raise InvalidOptionError(f"arenas must name each arena once, got {list(arenas)}")
        return listed


def _restore(checkpoint: Path) -> tuple[Any, Any, dict[str, Any]]:
    """BenchMARL's experiment of ``checkpoint``, rebuilt around one in-process arena and
    restored: its collection policy, the task's settings and blue's ``get_env_info()``."""
    from benchmarl.experiment import Experiment

    from neuronsmae.client.benchmarl.tasks import NeuronsMAEClass, face_of

    with open(checkpoint.parent.parent / CONFIG_FILE, "rb") as f:
        task, task_config, algorithm, model, seed, config, critic_model, _ = (
            pickle.load(f) for _ in range(8)
        )
    if not isinstance(task, NeuronsMAEClass):
        raise InvalidOptionError(
            f"{checkpoint}: a BenchMARL experiment of {task!r:.80}, not of a NeuronsMAE task"
        )
    if getattr(model, "is_rnn", False):
        raise InvalidOptionError(
            f"{checkpoint}: its model is recurrent ({type(model).__name__}), which this loader "
            "does not play; train with a feed-forward model (model=layers/mlp)"
        )
    task = NeuronsMAEClass(task.name, {**task_config, "env": "inprocess"})
    config = copy.copy(config)
    scratch = tempfile.mkdtemp(prefix="neuronsmae-benchmarl-")
    patch = {
        "restore_file": str(checkpoint), "restore_map_location": "cpu", "save_folder": scratch,
        "loggers": [], "create_json": False, "render": False, "evaluation": False,
        "sampling_device": "cpu", "train_device": "cpu", "buffer_device": "cpu",
        "on_policy_n_envs_per_worker": 1, "off_policy_n_envs_per_worker": 1,
        "evaluation_episodes": 1, "checkpoint_interval": 0, "checkpoint_at_end": False,
    }  # fmt: skip
    for key, value in patch.items():
        setattr(config, key, value)
    try:
        experiment = Experiment(
            task=task, algorithm_config=algorithm, model_config=model, seed=seed,
            config=config, critic_model_config=critic_model,
        )  # fmt: skip
        try:
            info = face_of(experiment.test_env).layout.info.to_dict()
            policy = experiment.policy
        finally:
            experiment.close()
    finally:
        shutil.rmtree(scratch, ignore_errors=True)
    return policy, task.settings, info
