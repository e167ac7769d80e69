"""Training configuration: one frozen dataclass of groups, built from defaults, a file and
overrides.

CleanRL style: every knob is a field with a docstring, so ``neuronsmae-train --help-config``
can print them. :class:`TrainConfig` holds what a run is (algorithm, opponent, budget,
sampling) at its top level and nests the groups: ``learner`` (:class:`LearnerConfig`, the
algorithm's hyper-parameters), ``eval`` (:class:`EvalConfig`), ``cluster``
(:class:`ClusterConfig`) and ``experimental`` (:class:`ExperimentalConfig`, off by default).

A key is a top-level name (``alg``), a group and a name (``learner.lr``), or a bare name that
exists in exactly one group (``lr``). A configuration is built in layers — defaults, then a
TOML or JSON file (flat, dotted keys, or ``[learner]``-style tables), then ``--set
key=value`` overrides, then the explicit command-line flags — and every layer rejects a key
the configuration does not have (:class:`ConfigError` lists the valid ones), so a typo can
never silently train with a default.
"""

from __future__ import annotations

import ast
import dataclasses
import difflib
import inspect
import itertools
import json
import numbers
import os
import sys
import types
import typing
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from neuronsmae.protocol.levels import LEVEL_ARGS
from neuronsmae.trainers.core.agent import epsilon_at
from neuronsmae.trainers.core.mixers import ALGORITHMS
from neuronsmae.trainers.play.pool import SelfPlayConfig, parse_opponents
from neuronsmae.trainers.play.task import ArenaGroup
from neuronsmae.trainers.run.config_groups import (
    ClusterConfig,
    ConfigError,
    EvalConfig,
    LearnerConfig,
    check_choice,
    check_finite,
    check_positive,
    check_types,
    parse_resources,
)
from neuronsmae.trainers.run.contexts import ContextSpec, ContextSpecError
from neuronsmae.trainers.run.experimental.config import ExperimentalConfig
from neuronsmae.trainers.run.presets import PRESETS, preset

__all__ = [
    "PRESETS",
    "ArenaGroup",
    "ClusterConfig",
    "ConfigError",
    "EvalConfig",
    "ExperimentalConfig",
    "LearnerConfig",
    "SelfPlayConfig",
    "TrainConfig",
    "field_docs",
    "make_config",
    "parse_overrides",
    "parse_resources",
    "preset",
    "read_config_file",
]

LEVELS = LEVEL_ARGS
"""Opponent bots of the cooperative task as a command line gives them: the paper's easy,
middle and hard, random, this project's variants middle_spread and hard_flank, and the
released build's levels "0" and "1" (docs/contexts.md, "Bots")."""
ENV_KINDS = ("inprocess", "remote")
"""``remote``: each worker owns a ``VecRM`` of its own vector server; ``inprocess``: each
owns a ``VecArena``."""
FIXED_ON_RESUME = (
    "alg", "learner.agent_hidden", "learner.mixer_embed", "learner.hypernet_hidden",
    "learner.features", "learner.head", "learner.last_action_input", "learner.agent_id_input",
    "learner.agent_net", "learner.hypernet_layers", "learner.mixer_state", "learner.replay",
    "arena.action_space", "arena.n_blue", "arena.n_red", "arena.observability", "arena.lidar",
    "arena.vector_obs", "arena.options",
)  # fmt: skip
"""Settings a resumed run keeps: they shape the networks in its checkpoint (the task's
settings set their input and output sizes; its reward and spawn may change)."""
SERVED_ONLY = ("base_port", "servers_per_worker", "servers", "server_resources", "router")
"""Cluster settings of the arenas' servers, meaningless with env=inprocess."""
MAX_RUN_SEED = 2**32 - 1
"""Largest run seed: the range every generator a run seeds accepts as it is; worker ``i``'s
arenas are seeded from ``seed × 1000`` on (trainers/run/train.py), far below an arena's limit."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything one training run needs; saved next to its checkpoints."""

    alg: str = "vdn"
    """Algorithm: iql (no mixer), vdn (sum) or qmix (monotonic hypernetwork mixer)."""
    level: str = "easy"
    """Red's bot: easy, middle or hard (the paper's), random, middle_spread, hard_flank (this
    project's variants), or "0" / "1" (the released build's levels). With ``opponent`` set,
    the bot every evaluation plays."""
    opponent: str = ""
    """Train against a pool instead of the ``level`` bot: a comma list of bot levels,
    checkpoint files or run directories, and ``self`` (snapshots of the learner, see the
    ``selfplay`` group); each training episode draws one member by δ-uniform sampling
    (trainers/play/pool.py). A policy on red needs equal teams and the blue layout it was trained
    on. Empty: every episode plays ``level``."""
    seed: int = 1
    """Seeds the networks, exploration, replay sampling and the training episodes, in
    [0, 2³²−1] (NumPy's, Python's and torch's generators all take it as it is)."""
    episodes: int = 30_000
    """Training episodes in total, ≥ 1 (a resumed run continues until this many). The default
    is the paper's budget (20 workers × 1,501 iterations = 30,020, rounded down to 1,500
    iterations); on a 2-core machine
    ``max_minutes`` ends the run long before it."""
    max_minutes: float = 30.0
    """Wall-clock budget of this invocation's training in minutes (0: none; a resumed run gets a
    fresh budget); the final evaluation follows. 30 minutes is the target run's budget
    (VDN against the easy bot, docs/results.md), so the default run is that run."""
    out: str = ""
    """Run directory; empty means runs/<alg>_<level>_s<seed>."""
    env: str = "remote"
    """remote: each worker launches its own vector server (the server command with
    ``--arenas envs_per_worker``, unpaced, on its node's loopback) and plays through a
    ``VecRM``, the design's served path; inprocess: each worker steps a ``VecArena`` in its
    own process (the client's ``env="inprocess"``)."""
    contexts: str = ""
    """Each training episode's reset contexts beyond ``level``, drawn per episode: ``;``
    -separated entries ``key=value`` (fixed), ``key=v1,v2,...`` (a uniform choice) or
    ``key=lo..hi`` (uniform in the range); keys as in docs/contexts.md. Empty: the
    defaults (coef 1, the chassis defaults). The authors trained at coef 0.5 with the
    released build's μ 0.5 for the learning team (``Friction_coeff=0.5;coef=0.5``, the
    ``paper`` preset's), and also randomised ``coef=0.5,0.7,1,1.4,1.7,2``
    (docs/reference.md, the context keys). See trainers/run/contexts.py."""
    workers: int = 0
    """Rollout workers (Ray actors), ≥ 0; 0 means one per core less one for the learner, and
    at least two (the paper: 20)."""
    envs_per_worker: int = 8
    """Arenas each worker plays at once, in [1, 64], with one batched forward pass of the
    agent network per decision for all of them (on a served worker: one request steps them
    all; docs/benchmarks.md, "The vector path"). The paper: one arena per worker."""
    sync: bool = False
    """Paper's loop: play an iteration of episodes, wait for all, then learn; else learn as
    episodes land (asynchronous)."""
    iteration_episodes: int = 0
    """sync: episodes per iteration, spread over the workers; 0 means one per worker. The
    paper's iteration is 20 (its 20 workers × 1 episode), whatever the worker count here."""
    torch_threads: int = 1
    """Torch intra-op threads for the learner, ≥ 1 (workers always use 1)."""
    progress: bool = True
    """Show the live tqdm progress bar."""
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    """The algorithm's hyper-parameters (keys ``learner.<name>``)."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    """Greedy evaluations, model selection and checkpoints (keys ``eval.<name>``)."""
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    """Ray cluster, worker placement and remote servers (keys ``cluster.<name>``)."""
    arena: ArenaGroup = field(default_factory=ArenaGroup)
    """The task: action space, team sizes, observability, LiDAR, reward, spawn and other
    arena options (keys ``arena.<name>``; trainers/play/task.py)."""
    selfplay: SelfPlayConfig = field(default_factory=SelfPlayConfig)
    """Snapshots of the learner and the opponent draw (keys ``selfplay.<name>``)."""
    experimental: ExperimentalConfig = field(default_factory=ExperimentalConfig)
    """Experiments, off by default (keys ``experimental.<name>``)."""

    def __post_init__(self) -> None:
        check_types(self)
        check_choice("alg", self.alg, sorted(ALGORITHMS))
        check_choice("level", self.level, LEVELS)
        fixed, self_play = parse_opponents(self.opponent)
        policies = self_play or any(m.is_policy for m in fixed)
        if policies and self.arena.n_blue != self.arena.n_red:
            raise ConfigError(
                f"opponent={self.opponent!r} puts a policy on red, which needs equal teams "
                f"(competitive mode); got arena.n_blue={self.arena.n_blue}, "
                f"arena.n_red={self.arena.n_red}"
            )
        if self.iteration_episodes < 0:
            raise ConfigError(f"iteration_episodes must be ≥ 0, got {self.iteration_episodes}")
        if self.learner.replay_ratio > 0 and self.sync:
            raise ConfigError(
                "learner.replay_ratio > 0 decouples learning from sampling, which the "
                "synchronous loop (sync=true, the paper's) does not: give one or the other"
            )
        if self.learner.eps_schedule == "iterations" and not (
            self.sync and self.iteration_episodes
        ):
            raise ConfigError(
                "learner.eps_schedule='iterations' steps ε once per iteration: it needs "
                f"sync=true and iteration_episodes ≥ 1, got sync={self.sync}, "
                f"iteration_episodes={self.iteration_episodes}"
            )
        try:
            ContextSpec.parse(self.contexts)
        except ContextSpecError as err:
            raise ConfigError(str(err)) from None
        check_choice("env", self.env, ENV_KINDS)
        check_positive(self, "episodes", "torch_threads", "envs_per_worker")
        if self.envs_per_worker > 64:
            raise ConfigError(f"envs_per_worker must be in [1, 64], got {self.envs_per_worker}")
        for name in ("groups", "servers_per_worker"):
            if getattr(self.cluster, name) > self.envs_per_worker:
                raise ConfigError(
                    f"cluster.{name} must be in [1, envs_per_worker={self.envs_per_worker}], "
                    f"got {getattr(self.cluster, name)}"
                )
        self._check_served_settings()
        check_finite(self)
        if not 0 <= self.seed <= MAX_RUN_SEED:
            raise ConfigError(f"seed must be in [0, {MAX_RUN_SEED}], got {self.seed}")
        if self.workers < 0 or self.max_minutes < 0:
            raise ConfigError(
                f"workers and max_minutes must be ≥ 0, got {self.workers} and {self.max_minutes}"
            )

    def _check_served_settings(self) -> None:
        """Refuse server settings where no server runs (env=inprocess would ignore them),
        and a fleet's ports past 65535."""
        cluster, default = self.cluster, ClusterConfig()
        set_ = [name for name in SERVED_ONLY if getattr(cluster, name) != getattr(default, name)]
        if self.env == "inprocess" and set_:
            raise ConfigError(
                f"cluster.{', cluster.'.join(set_)} {'applies' if len(set_) == 1 else 'apply'} "
                "only to env=remote (the arenas' servers); env=inprocess plays the arenas "
                "inside the workers"
            )
        last = cluster.base_port + self.n_workers() - 1
        if cluster.base_port and last > 65535:
            raise ConfigError(
                f"cluster.base_port={cluster.base_port} with {self.n_workers()} workers needs "
                f"ports up to {last}; the last port is 65535"
            )

    @property
    def run_dir(self) -> Path:
        """The run directory, defaulting to runs/<alg>_<level>_s<seed>."""
        return Path(self.out or f"runs/{self.alg}_{self.level}_s{self.seed}")

    def epsilon(self, k: int) -> float:
        """ε of training episode ``k`` (from 0) under ``learner.eps_schedule``."""
        lc = self.learner
        if lc.eps_schedule == "iterations":
            per = self.iteration_episodes
            step = (lc.eps_start - lc.eps_end) * per / max(lc.eps_anneal_episodes, 1)
            return max(lc.eps_end, lc.eps_start - (k // per + 1) * step)
        return epsilon_at(k, lc.eps_start, lc.eps_end, lc.eps_anneal_episodes)

    def iteration_size(self, n_workers: int) -> int:
        """sync: episodes per iteration (``iteration_episodes``, or one per worker)."""
        return self.iteration_episodes or n_workers

    def n_workers(self) -> int:
        """Worker count: as configured, else one per core less one for the learner (≥ 2)."""
        return self.workers or max(2, (os.cpu_count() or 2) - 1)

    def to_dict(self) -> dict[str, Any]:
        """Plain values, the groups as nested dicts (JSON- and
        ``torch.load(weights_only=True)``-safe)."""
        return dataclasses.asdict(self)


GROUPS: dict[str, type] = {
    "learner": LearnerConfig,
    "eval": EvalConfig,
    "cluster": ClusterConfig,
    "arena": ArenaGroup,
    "selfplay": SelfPlayConfig,
    "experimental": ExperimentalConfig,
}
"""The groups nested in :class:`TrainConfig`, by field name."""

# --- keys ------------------------------------------------------------------------------


def _fields(cls: type) -> Iterator[tuple[str, Any]]:
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        yield f.name, hints[f.name]


def _key_types() -> dict[str, Any]:
    """Every key in full (``alg``, ``learner.lr``, ...) and its field's type, top level first."""
    keys = {name: kind for name, kind in _fields(TrainConfig) if name not in GROUPS}
    for group, cls in GROUPS.items():
        keys.update({f"{group}.{name}": kind for name, kind in _fields(cls)})
    return keys


KEYS = _key_types()
"""Every configuration key in full and its type."""


def _resolve(key: str, where: str) -> str:
    """The full key ``key`` names: itself, or the one group key whose name it is."""
    if key in KEYS:
        return key
    matches = [full for full in KEYS if full.rpartition(".")[2] == key]
    if len(matches) == 1:
        return matches[0]
    if matches:
        raise ConfigError(f"config key {key!r} in {where} is ambiguous: use one of {matches}")
    names = [*KEYS, *(full.rpartition(".")[2] for full in KEYS if "." in full)]
    hint = difflib.get_close_matches(key, names, n=1)
    said = f"{key!r}" + (f" (did you mean {hint[0]!r}?)" if hint else "")
    if key in GROUPS:
        said += f" (a group: set {key}.<name>, or give a table of its keys)"
    raise ConfigError(f"unknown config key {said} in {where}; valid: {', '.join(KEYS)}")


def flatten(layer: Mapping[str, Any], where: str) -> dict[str, Any]:
    """A layer's keys in full: dotted and bare keys resolved, group tables opened."""
    out: dict[str, Any] = {}
    for key, value in layer.items():
        if key in GROUPS and isinstance(value, Mapping):
            inner = flatten({f"{key}.{k}": v for k, v in value.items()}, where)
            out.update(inner)
        else:
            out[_resolve(str(key), where)] = value
    return out


def _coerce(key: str, value: Any) -> Any:
    """Convert a file or command-line value to the field's type, or raise ConfigError."""
    kind = KEYS[key]
    if isinstance(kind, types.UnionType):
        kind = next(a for a in typing.get_args(kind) if a is not type(None))
    if isinstance(value, str) and kind is not str:
        text = value.strip().lower()
        if kind is bool:
            if text not in ("true", "false", "1", "0", "yes", "no"):
                raise ConfigError(f"{key} expects a bool (true/false), got {value!r}")
            return text in ("true", "1", "yes")
        try:
            number = float(text) if kind is int and "e" in text else kind(text)
        except ValueError:
            raise ConfigError(f"{key} expects {kind.__name__}, got {value!r}") from None
        if isinstance(number, float) and kind is int:  # 1e5; not 2.5e0 nor 1e400
            if not number.is_integer():
                raise ConfigError(f"{key} expects a whole number, got {value!r}")
            return int(number)
        return number
    number = isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))
    if kind is float and number:  # Python or NumPy
        return float(value)
    if kind is int and number and float(value).is_integer():
        return int(value)
    if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
        raise ConfigError(f"{key} expects {kind.__name__}, got {value!r}")
    return value


def field_docs() -> dict[str, str]:
    """Each key's docstring, read from the source, in :data:`KEYS` order (``--help-config``)."""
    docs: dict[str, str] = {}
    for prefix, cls in [("", TrainConfig), *((f"{g}.", c) for g, c in GROUPS.items())]:
        body = ast.parse(inspect.getsource(cls)).body[0].body  # type: ignore[attr-defined]
        for node, after in itertools.pairwise(body):
            if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr):
                name = node.target.id  # type: ignore[attr-defined]
                docs[prefix + name] = str(after.value.value)  # type: ignore[attr-defined]
    return {key: docs[key] for key in KEYS}


# --- layers ----------------------------------------------------------------------------


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a TOML or JSON file of config keys (top-level keys, dotted keys or group tables,
    optionally all under a ``[train]`` table); return them in full."""
    p = Path(path)
    if p.suffix == ".toml":
        if sys.version_info < (3, 11):
            raise ConfigError("TOML config files need Python ≥ 3.11; use a .json file")
        import tomllib

        parse, malformed = tomllib.loads, tomllib.TOMLDecodeError
    elif p.suffix == ".json":
        parse, malformed = json.loads, json.JSONDecodeError
    else:
        raise ConfigError(f"config file {p} must end in .toml or .json")
    try:
        data = parse(p.read_text())
    except (malformed, UnicodeDecodeError) as exc:
        raise ConfigError(f"config file {p} is not valid {p.suffix[1:].upper()}: {exc}") from None
    if not isinstance(data, dict):
        raise ConfigError(
            f"config file {p} must hold a table of config keys, got {type(data).__name__}"
        )
    if isinstance(data.get("train"), dict) and len(data) == 1:
        data = data["train"]
    return flatten(data, str(p))


def parse_overrides(items: Iterable[str]) -> dict[str, str]:
    """``["key=value", ...]`` → ``{full key: value}``; values are coerced later."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects key=value, got {item!r}")
        out[_resolve(key.strip(), "--set")] = value
    return out


def make_config(*layers: Mapping[str, Any], base: TrainConfig | None = None) -> TrainConfig:
    """Apply the layers in order over ``base`` (fresh defaults if none), checking each key.

    A layer's keys may be full, bare or group tables (a saved ``config.json`` is one layer).
    """
    if base is not None and not isinstance(base, TrainConfig):
        raise ConfigError(f"base must be a TrainConfig, got {type(base).__name__}")
    values = (base or TrainConfig()).to_dict()
    for i, layer in enumerate(layers):
        if not isinstance(layer, Mapping):
            raise ConfigError(
                f"layer {i} must be a mapping of config keys, got {type(layer).__name__}"
            )
        for key, value in flatten(layer, f"layer {i}").items():
            group, _, name = key.rpartition(".")
            (values[group] if group else values)[name] = _coerce(key, value)
    groups = {name: cls(**values.pop(name)) for name, cls in GROUPS.items()}
    return TrainConfig(**values, **groups)


def check_resumable(saved: TrainConfig, cfg: TrainConfig) -> None:
    """Refuse a resumed run's config that changes a :data:`FIXED_ON_RESUME` setting of the
    saved one, naming each (its checkpoint's networks would not fit)."""
    before, after = saved.to_dict(), cfg.to_dict()

    def value(config: dict[str, Any], key: str) -> Any:
        group, _, name = key.rpartition(".")
        return config[group][name] if group else config[key]

    changed = [
        f"{key} {value(before, key)!r} -> {value(after, key)!r}"
        for key in FIXED_ON_RESUME
        if value(before, key) != value(after, key)
    ]
    if changed:
        raise ConfigError(
            f"--resume keeps the settings that shape the run's networks; this changes "
            f"{'; '.join(changed)}. Start a new run (another --out) to train with them"
        )
