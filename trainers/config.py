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
import os
import sys
import types
import typing
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from neuronsmae.trainers.config_groups import (
    ClusterConfig,
    ConfigError,
    EvalConfig,
    LearnerConfig,
    check_choice,
    check_positive,
    parse_resources,
)
from neuronsmae.trainers.experimental.config import ExperimentalConfig
from neuronsmae.trainers.mixers import ALGORITHMS

__all__ = [
    "ClusterConfig",
    "ConfigError",
    "EvalConfig",
    "ExperimentalConfig",
    "LearnerConfig",
    "TrainConfig",
    "field_docs",
    "make_config",
    "parse_overrides",
    "parse_resources",
    "preset",
    "read_config_file",
]

LEVELS = ("easy", "middle", "hard")
"""Opponent bot levels of the cooperative task."""
ENV_KINDS = ("inprocess", "remote")
"""``remote``: each worker owns a ``VecRM`` of its own vector server; ``inprocess``: each
owns a ``VecArena``."""


@dataclass(frozen=True)
class TrainConfig:
    """Everything one training run needs; saved next to its checkpoints."""

    alg: str = "vdn"
    """Algorithm: iql (no mixer), vdn (sum) or qmix (monotonic hypernetwork mixer)."""
    level: str = "easy"
    """Opponent bot level: easy, middle or hard."""
    seed: int = 1
    """Seeds the networks, exploration, replay sampling and the training episodes."""
    episodes: int = 30_000
    """Training episodes in total, ≥ 1 (a resumed run continues until this many). The default
    is the paper's budget (20 workers × 1,501 iterations); on a 2-core machine
    ``max_minutes`` ends the run long before it."""
    max_minutes: float = 30.0
    """Wall-clock budget of this session's training in minutes (0: none; a resumed run gets a
    fresh budget); the final evaluation follows. 30 minutes is the target run's budget
    (VDN against the easy bot, docs/results.md), so the default run is that run."""
    out: str = ""
    """Run directory; empty means runs/<alg>_<level>_s<seed>."""
    env: str = "remote"
    """remote: each worker launches its own vector server (``neuronsmae-server --arenas
    envs_per_worker``, unpaced, on its node's loopback) and plays through a ``VecRM``, the
    design's served path; inprocess: each worker steps a ``VecArena`` in its own process."""
    coef: float = 1.0
    """Context 'coef': multiplies the damage the bots deal."""
    workers: int = 0
    """Rollout workers (Ray actors); 0 means one per core less one for the learner, and at
    least two. Measured on 2 cores: two half-CPU workers beside the learner play 25 % more
    episodes in 30 minutes than one (``python bench/bench_learning.py --workers 1`` against
    the default two)."""
    envs_per_worker: int = 8
    """Arenas each worker plays at once, in [1, 64], with one batched forward pass of the
    agent network per decision for all of them. 8 gives a served arena at least 0.85 of an
    in-process arena's CPU efficiency (``python -m bench.bench_vector``)."""
    sync: bool = False
    """Paper's loop: one episode from every worker, then learn; else learn as episodes land."""
    torch_threads: int = 1
    """Torch intra-op threads for the learner (workers always use 1)."""
    progress: bool = True
    """Show the live tqdm progress bar."""
    learner: LearnerConfig = field(default_factory=LearnerConfig)
    """The algorithm's hyper-parameters (keys ``learner.<name>``)."""
    eval: EvalConfig = field(default_factory=EvalConfig)
    """Greedy evaluations, model selection and checkpoints (keys ``eval.<name>``)."""
    cluster: ClusterConfig = field(default_factory=ClusterConfig)
    """Ray cluster, worker placement and remote servers (keys ``cluster.<name>``)."""
    experimental: ExperimentalConfig = field(default_factory=ExperimentalConfig)
    """Experiments, off by default (keys ``experimental.<name>``)."""

    def __post_init__(self) -> None:
        check_choice("alg", self.alg, sorted(ALGORITHMS))
        check_choice("level", self.level, LEVELS)
        check_choice("env", self.env, ENV_KINDS)
        check_positive(self, "episodes", "torch_threads", "envs_per_worker")
        if self.envs_per_worker > 64:
            raise ConfigError(f"envs_per_worker must be in [1, 64], got {self.envs_per_worker}")
        if self.workers < 0 or self.max_minutes < 0:
            raise ConfigError(
                f"workers and max_minutes must be ≥ 0, got {self.workers} and {self.max_minutes}"
            )
        for name, kind in GROUPS.items():
            if not isinstance(getattr(self, name), kind):
                raise ConfigError(f"{name} must be a {kind.__name__}")

    @property
    def run_dir(self) -> Path:
        """The run directory, defaulting to runs/<alg>_<level>_s<seed>."""
        return Path(self.out or f"runs/{self.alg}_{self.level}_s{self.seed}")

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
    "experimental": ExperimentalConfig,
}
"""The groups nested in :class:`TrainConfig`, by field name."""

PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "learner.lr": 5e-4,
        "learner.td_lambda": 0.0,
        "learner.target_update_interval": 5,
        "learner.features": "raw",
        "learner.head": "flat",
        "learner.augment": "none",
        "sync": True,
        "learner.train_every": 1,
        "learner.updates_per_round": 1,
        "learner.eps_anneal_episodes": 2000,
        "max_minutes": 0.0,
        "episodes": 30_000,
    },
}
"""Named layers applied before the config file: ``paper`` restores the paper's settings
(synchronous loop of one episode per worker and one update per iteration, Adam 5e-4,
one-step targets, targets refreshed every 5 iterations, raw observations, flat Q head, no
augmentation) where the defaults were tuned to learn within a laptop's half hour; 30 000
episodes is the paper's 20 workers × 1501 iterations (run it with ``--workers 20`` to
match)."""


def preset(name: str) -> dict[str, Any]:
    """The preset layer called ``name``; raise listing the valid ones."""
    try:
        return dict(PRESETS[name])
    except KeyError:
        raise ConfigError(f"unknown preset {name!r}; valid: {', '.join(sorted(PRESETS))}") from None


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
            return kind(float(text)) if kind is int and "e" in text else kind(text)
        except ValueError:
            raise ConfigError(f"{key} expects {kind.__name__}, got {value!r}") from None
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if kind is int and isinstance(value, float) and value.is_integer():
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

        data = tomllib.loads(p.read_text())
    elif p.suffix == ".json":
        data = json.loads(p.read_text())
    else:
        raise ConfigError(f"config file {p} must end in .toml or .json")
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
    values = (base or TrainConfig()).to_dict()
    for i, layer in enumerate(layers):
        for key, value in flatten(layer, f"layer {i}").items():
            group, _, name = key.rpartition(".")
            (values[group] if group else values)[name] = _coerce(key, value)
    groups = {name: cls(**values.pop(name)) for name, cls in GROUPS.items()}
    return TrainConfig(**values, **groups)
