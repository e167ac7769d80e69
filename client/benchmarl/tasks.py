"""NeuronsMAE as a BenchMARL task family: :class:`NeuronsMAETask` and :class:`NeuronsMAEClass`.

Built on BenchMARL's own extension points: a ``Task`` enum whose members are the tasks, and a
``TaskClass`` (here a subclass of BenchMARL's ``PettingZooClass``, whose spec methods split a
TorchRL ``PettingZooWrapper``'s specs into observation, info, action mask and state) that
builds each environment. Every environment is the PettingZoo face
(:func:`neuronsmae.client.pz_env.parallel_env`, masks in the infos) in TorchRL's
``PettingZooWrapper``:

* group ``blue`` (blue's robots learn; red is the arena's bot, ``level``);
* observation ``("blue", "observation")``, ``[n_blue, obs_dim]``;
* action ``("blue", "action")``: categorical for abstract and discrete actions, with the mask
  at ``("blue", "action_mask")``; ``[n_blue, 4]`` rows ``(vx, vy, omega, target)`` for
  continuous ones (the target read as a bin, enemy ``i`` is ``[i, i + 1)``; its mask is in the
  infos as ``("blue", "info", "target_mask")``);
* ``"state"``: the arena's global state, for centralised critics and mixers;
* ``("blue", "info", ...)``: the face's numeric infos (``battle_won``, ``episode_limit``, ...);
* ``max_steps``: the arena's ``episode_limit`` in decisions.

BenchMARL vectorises these environments itself (``SerialEnv``, or ``ParallelEnv`` with
``experiment.parallel_collection``): each sub-environment has its own arena, on a private
server or in process (``env`` below). Environment ``i`` built from one
:meth:`~NeuronsMAEClass.get_env_fun` is seeded ``seed + i`` (``SerialEnv`` builds them in one
process; the copies of the factory a ``ParallelEnv`` ships to its workers share one seed).

A task's configuration (its YAML file under ``conf/task/neuronsmae/``, or the dict given to
``NeuronsMAETask.X.get_task(config)``) holds the fields of :class:`TaskSettings`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import yaml
from benchmarl.environments import PettingZooClass, Task, task_config_registry
from tensordict import TensorDictBase
from torchrl.envs import EnvBase
from torchrl.envs.libs.pettingzoo import PettingZooWrapper

from neuronsmae.client.pz_env import ArenaParallelEnv, parallel_env
from neuronsmae.protocol.env_info import ACTION_SPACES, ARENA_OPTIONS
from neuronsmae.protocol.errors import InvalidOptionError
from neuronsmae.protocol.levels import level_error, level_value

ENV_NAME = "neuronsmae"
"""The environment's name in BenchMARL (``task=neuronsmae/<task>`` on its command line)."""
CONF = Path(__file__).parent / "conf"
"""The folder of the tasks' YAML files (``task/neuronsmae/<task>.yaml``), for Hydra's
search path."""
GROUP = "blue"
"""The agent group that learns: blue's robots."""
DEFAULT_ACTION_SPACE = "abstract"
"""The arena's ``action_space`` when ``options`` does not set one."""


@dataclass(frozen=True)
class TaskSettings:
    """A NeuronsMAE task's configuration, checked (:meth:`from_config`)."""

    env: str | None = None
    """Where each environment's arena runs: None, a private unpaced server per environment
    (stopped when the environment closes); ``"inprocess"`` (or ``"neuronsmae.server:Arena"``,
    any ``"module:attr"`` naming an arena class), in the environment's process: the faces'
    ``env=``."""
    level: str | int = "easy"
    """Red's bot, the ``level`` context of every episode: ``easy``, ``middle``, ``hard`` or
    any other level the arena takes (docs/contexts.md, "Bots")."""
    contexts: Mapping[str, Any] = field(default_factory=dict)
    """Other reset contexts of every episode (dynamics, ``coef``, ...; docs/contexts.md);
    checked by the arena at the first reset."""
    options: Mapping[str, Any] = field(default_factory=dict)
    """Arena options (docs/options.md): ``action_space``, ``n_blue``, ``n_red``,
    ``episode_steps``, ...; not ``mode``, which is the task's (cooperative)."""

    @classmethod
    def from_config(cls, config: Mapping[str, Any] | None) -> TaskSettings:
        """Check a task's configuration; :class:`InvalidOptionError` names the field and what
        is valid."""
        config = {} if config is None else config
        if not isinstance(config, Mapping):
            raise InvalidOptionError(
                f"a NeuronsMAE task's config must be a dict of {_fields()}, got {config!r:.80}"
            )
        unknown = sorted(set(config) - set(_fields()))
        if unknown:
            raise InvalidOptionError(
                f"NeuronsMAE task: unknown field(s) {unknown}; valid fields: {_fields()}"
            )
        settings = cls(**config)
        settings._check()
        return settings

    def _check(self) -> None:
        if self.env is not None and (
            not isinstance(self.env, str) or (self.env != "inprocess" and ":" not in self.env)
        ):
            raise InvalidOptionError(
                f"env={self.env!r:.80}: null (a private server per environment), 'inprocess', "
                "or a 'module:attr' name of an arena class such as 'neuronsmae.server:Arena'"
            )
        if level_value(self.level) is None:
            raise InvalidOptionError(level_error("level", self.level))
        for name in ("contexts", "options"):
            if not isinstance(getattr(self, name), Mapping):
                raise InvalidOptionError(f"{name} must be a dict, got {getattr(self, name)!r:.80}")
        if "level" in self.contexts:
            raise InvalidOptionError(
                "contexts['level']: red's bot is the task's field 'level'; set it there"
            )
        unknown = sorted(set(self.options) - (ARENA_OPTIONS - {"mode"}))
        if unknown:
            raise InvalidOptionError(
                f"options: {unknown} are not arena options a task sets (mode is the task's: "
                f"cooperative); valid: {sorted(ARENA_OPTIONS - {'mode'})}"
            )
        if self.action_space not in ACTION_SPACES:
            raise InvalidOptionError(
                f"options['action_space']={self.action_space!r}; valid: {list(ACTION_SPACES)}"
            )

    @property
    def action_space(self) -> str:
        """The arena's action space: ``abstract``, ``discrete`` or ``continuous``."""
        return str(self.options.get("action_space", DEFAULT_ACTION_SPACE))

    @property
    def continuous(self) -> bool:
        return self.action_space == "continuous"

    def face_kwargs(self) -> dict[str, Any]:
        """The PettingZoo face's arguments (without its seed)."""
        contexts = {**self.contexts, "level": self.level}
        return {"env": self.env, "masks": "info", "contexts": contexts, **self.options,
                "mode": "cooperative"}  # fmt: skip

    def to_config(self) -> dict[str, Any]:
        """Plain values, as BenchMARL keeps and logs a task's config."""
        return {
            "env": self.env,
            "level": self.level,
            "contexts": dict(self.contexts),
            "options": dict(self.options),
        }


def _fields() -> list[str]:
    return [f.name for f in dataclasses.fields(TaskSettings)]


class ArenaEnvFactory:
    """What :meth:`NeuronsMAEClass.get_env_fun` returns: each call builds one environment
    (a face with its own arena in a ``PettingZooWrapper``), the ``i``-th seeded
    ``seed + i`` (None: each draws its seed from the operating system). Picklable, for
    BenchMARL's ``config.pkl`` and TorchRL's ``ParallelEnv``."""

    def __init__(self, settings: TaskSettings, seed: int | None, device: Any) -> None:
        self.settings, self.seed, self.device = settings, seed, device
        self.built = 0
        """Environments built so far."""

    def __call__(self) -> PettingZooWrapper:
        seed = None if self.seed is None else int(self.seed) + self.built
        self.built += 1
        face = parallel_env(seed=seed, **self.settings.face_kwargs())
        try:
            return PettingZooWrapper(
                env=face,
                return_state=True,
                group_map={GROUP: list(face.possible_agents)},
                categorical_actions=True,
                seed=seed,
                device=self.device,
            )
        except BaseException:
            face.close()
            raise


def face_of(env: EnvBase) -> ArenaParallelEnv:
    """The NeuronsMAE face inside an environment :class:`ArenaEnvFactory` built (through
    BenchMARL's ``TransformedEnv`` layers)."""
    inner: Any = env
    while not isinstance(inner, PettingZooWrapper):
        base = getattr(inner, "base_env", None)
        if base is None or base is inner:
            raise InvalidOptionError(
                f"{type(env).__name__} holds no NeuronsMAE environment (built by "
                "NeuronsMAEClass.get_env_fun)"
            )
        inner = base
    face = inner._env
    if not isinstance(face, ArenaParallelEnv):
        raise InvalidOptionError(f"{type(face).__name__} is not a NeuronsMAE face")
    return face


class NeuronsMAEClass(PettingZooClass):
    """A NeuronsMAE task. Its ``config`` (a dict of :class:`TaskSettings`' fields) is checked
    when the task is made and again whenever it is read (:attr:`settings`), so it may be
    changed in place as BenchMARL's examples do (``task.config["level"] = "middle"``)."""

    def __init__(self, name: str, config: Mapping[str, Any] | None) -> None:
        super().__init__(name=name, config=TaskSettings.from_config(config).to_config())

    @property
    def settings(self) -> TaskSettings:
        """The task's ``config``, checked."""
        return TaskSettings.from_config(self.config)

    def get_env_fun(
        self, num_envs: int, continuous_actions: bool, seed: int | None, device: Any
    ) -> Callable[[], EnvBase]:
        """One environment per call (BenchMARL vectorises them); ``num_envs`` is not used."""
        if continuous_actions != self.settings.continuous:
            raise InvalidOptionError(
                f"{self.name.lower()}: continuous_actions={continuous_actions}, but its arena's "
                f"action_space is {self.settings.action_space!r}"
            )
        return ArenaEnvFactory(self.settings, seed, device)

    def supports_continuous_actions(self) -> bool:
        return self.settings.continuous

    def supports_discrete_actions(self) -> bool:
        return not self.settings.continuous

    def has_state(self) -> bool:
        return True

    def has_render(self, env: EnvBase) -> bool:
        return False

    def max_steps(self, env: EnvBase) -> int:
        """The arena's ``episode_limit`` (decisions per episode at most)."""
        return face_of(env).layout.episode_limit

    @staticmethod
    def log_info(batch: TensorDictBase) -> dict[str, float]:
        """Over the episodes that ended in ``batch``: blue's win rate, the share ended by the
        time limit, and blue's team figures at the end (:data:`TEAM_FIGURES`).

        BenchMARL also logs every info itself as ``collection/blue/info/<key>``, the mean
        over all its entries: for the per-robot arrays (blue robots first, then red) that
        mixes both teams (``damage_dealt`` then equals ``damage_taken``: both are the HP
        lost in the episode over four robots), so the team's own figures are logged here.
        """
        done = batch.get(("next", "done")).squeeze(-1)
        if not bool(done.any()):
            return {}
        out = {}
        for key, name in (("battle_won", "win_rate"), ("episode_limit", "episode_limit_rate")):
            value = batch.get(("next", GROUP, "info", key))[done]
            out[f"collection/info/{name}"] = value[..., 0].to(torch.float).mean().item()
        for key, (name, reduce) in TEAM_FIGURES.items():
            value = batch.get(("next", GROUP, "info", key))[done]  # [episodes, agents, robots]
            blue = value[:, 0, : value.shape[1]].to(torch.float)  # agent 0's view, blue robots
            team = blue.sum(-1) if reduce == "sum" else blue.mean(-1)
            out[f"collection/info/{name}"] = team.mean().item()
        return out

    @staticmethod
    def env_name() -> str:
        return ENV_NAME


TEAM_FIGURES: dict[str, tuple[str, str]] = {
    "damage_dealt": ("blue_damage_dealt", "sum"),
    "damage_taken": ("blue_damage_taken", "sum"),
    "bullets_fraction": ("blue_bullets_left", "mean"),
    "hp_fraction": ("blue_hp_left", "mean"),
}
"""Per-robot infos logged for blue's robots alone at each episode's end, by
:meth:`NeuronsMAEClass.log_info`: info key → (``collection/info/<name>``, over blue's robots:
``sum`` of HP, or ``mean`` of fractions)."""


class NeuronsMAETask(Task):
    """The NeuronsMAE tasks; ``NeuronsMAETask.COOP_ABSTRACT.get_from_yaml()`` loads a task
    with its defaults, ``.get_task(config)`` with a config of :class:`TaskSettings`' fields."""

    COOP_ABSTRACT = None
    COOP_DISCRETE = None
    COOP_CONTINUOUS = None
    COOP_3V3 = None

    @staticmethod
    def associated_class() -> type[NeuronsMAEClass]:
        return NeuronsMAEClass

    def get_from_yaml(self, path: str | None = None) -> NeuronsMAEClass:
        """The task with the configuration in ``path`` (default: this package's
        ``conf/task/neuronsmae/<task>.yaml``)."""
        file = CONF / "task" / ENV_NAME / f"{self.name.lower()}.yaml" if path is None else path
        with open(file, encoding="utf-8") as f:
            config = yaml.safe_load(f) or {}
        config.pop("defaults", None)
        return self.get_task(config=config)  # type: ignore[return-value]

    def get_task(self, config: Mapping[str, Any] | None = None) -> NeuronsMAEClass:
        """The task with ``config`` (None: its YAML defaults)."""
        if config is None:
            return self.get_from_yaml()
        return NeuronsMAEClass(name=self.name, config=config)


def register() -> None:
    """Make the tasks known to BenchMARL's task registry as ``neuronsmae/<task>``, which its
    Hydra loader reads (idempotent; done on import)."""
    for task in NeuronsMAETask:
        task_config_registry[f"{ENV_NAME}/{task.name.lower()}"] = task


register()
