"""Training configuration: one frozen dataclass, built from defaults, a file and overrides.

CleanRL style: every knob is a field with a docstring, so ``neuronsmae-train --help-config``
can print them. A configuration is built in layers — defaults, then a TOML or JSON file, then
``--set key=value`` overrides, then the explicit command-line flags — and every layer rejects
a key the dataclass does not have (:class:`ConfigError` lists the valid ones), so a typo can
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
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from neuronsmae.trainers.features import FEATURES, POINT_FEATURES
from neuronsmae.trainers.mixers import ALGORITHMS
from neuronsmae.trainers.symmetry import parse_generators

LEVELS = ("easy", "middle", "hard")
"""Opponent bot levels of the cooperative task."""
ENV_KINDS = ("inprocess", "remote")
"""``inprocess``: each worker owns an ``Arena``; ``remote``: each owns an ``RM`` client."""

SERVER_PLACEMENTS = ("local", "actors")
"""``remote``: where each worker's server runs (see ``trainers/placement.py``)."""


class ConfigError(ValueError):
    """An unknown key, a value of the wrong type, or a value out of range."""


def parse_resources(text: str) -> dict[str, float]:
    """``"sampler=1,big_node=0.5"`` → ``{"sampler": 1.0, "big_node": 0.5}`` ("" → {}).

    Only custom resources: CPUs are ``worker_cpus``, and Ray owns the built-in names.
    """
    out: dict[str, float] = {}
    for item in filter(None, (part.strip() for part in text.split(","))):
        name, sep, amount = (x.strip() for x in item.partition("="))
        try:
            value = float(amount) if sep else 1.0
        except ValueError:
            raise ConfigError(f"resource {item!r}: expected name=amount") from None
        if not name or value <= 0 or name in ("CPU", "GPU", "memory", "object_store_memory"):
            raise ConfigError(f"resource {item!r}: expected a custom name and an amount > 0")
        out[name] = value
    return out


@dataclass(frozen=True)
class TrainConfig:
    """Everything one training run needs; saved next to its checkpoints."""

    # --- experiment --------------------------------------------------------------------
    alg: str = "vdn"
    """Algorithm: iql (no mixer), vdn (sum) or qmix (monotonic hypernetwork mixer)."""
    level: str = "easy"
    """Opponent bot level: easy, middle or hard."""
    seed: int = 1
    """Seeds the networks, exploration, replay sampling and the training episodes."""
    episodes: int = 30_000
    """Training episodes in total (a resumed run continues until this many). The default is
    the paper's budget (20 workers × 1,501 iterations); on a 2-core machine ``max_minutes``
    ends the run long before it."""
    max_minutes: float = 30.0
    """Wall-clock budget of this session's training in minutes (0: none; a resumed run gets a
    fresh budget); the final evaluation follows. 30 minutes is the target run's budget
    (VDN against the easy bot, docs/results.md), so the default run is that run."""
    out: str = ""
    """Run directory; empty means runs/<alg>_<level>_s<seed>."""
    # --- environment -------------------------------------------------------------------
    env: str = "inprocess"
    """inprocess: each worker owns an Arena; remote: each owns an RM client of its server."""
    base_port: int = 10000
    """remote: worker i talks to the server on base_port + i."""
    coef: float = 1.0
    """Context 'coef': multiplies the damage the bots deal."""
    # --- sampling ----------------------------------------------------------------------
    workers: int = 0
    """Rollout workers (Ray actors); 0 means one per core less one for the learner, and at
    least two: on 2 cores, two half-CPU workers beside the learner bought 25 % more episodes
    in 30 minutes than one (docs/results.md, runs A and B), and the target run uses two."""
    worker_cpus: float = 0.5
    """CPUs Ray reserves per worker (fractions let workers share a core with the learner)."""
    sync: bool = False
    """Paper's loop: one episode from every worker, then learn; else learn as episodes land."""
    address: str = ""
    """Ray cluster to join (ray.init address); empty always starts a new local Ray."""
    max_worker_failures: int = 5
    """Consecutive failures after which a worker is given up instead of restarted."""
    worker_resources: str = ""
    """Custom Ray resources each worker also requires, "name=amount[,...]" (e.g. "sampler=1"
    puts workers only on nodes started with --resources '{"sampler": N}', N per node)."""
    servers: str = "local"
    """remote: local (each worker launches its server on its own node, loopback only) or
    actors (a Ray actor per worker runs its server on a node Ray picks, reached by node IP)."""
    server_resources: str = ""
    """servers=actors: custom Ray resources each server actor requires, like worker_resources."""
    router: str = ""
    """remote: reach server base_port + i through this Zenoh router (tcp/host:7447) instead;
    the servers run outside Ray (neuronsmae-serve --router). See deploy/README.md."""
    # --- learning ----------------------------------------------------------------------
    lr: float = 5e-4
    """Adam learning rate (paper: 5e-4). 1e-3 reaches 0.8 against the easy bot sooner but
    stays there; 5e-4 climbs higher (docs/results.md)."""
    gamma: float = 0.99
    """Discount (paper: 0.99)."""
    eps_start: float = 0.2
    """Initial exploration ε (paper: 0.2)."""
    eps_end: float = 0.05
    """Final exploration ε (paper: 0.05)."""
    eps_anneal_episodes: int = 1500
    """Training episodes over which ε falls linearly from eps_start to eps_end."""
    start_replay: float = 0.0
    """Probability that a training episode replays a recent start the team did not win
    instead of a fresh seed (0: never, the paper's uniform starts); see trainers/starts.py.
    Why: the agents lose mostly the starts they already judge bad, and uniform seeds give
    those starts only their small share of the data. With 0.3, VDN against the easy bot
    tested at 0.955, 0.92 and 0.935 on seeds 1–3 where the defaults read 0.91, 0.905 and
    0.93 (docs/results.md, runs AI–AK against AF–AH). It learns sooner more than it learns
    better: validation from 9,000 episodes on averages the same (0.915 against 0.923).
    Off by default: the defaults keep the paper's uniform starts, so a default run measures
    the algorithm the paper measured."""
    start_replay_plays: int = 3
    """A lost start is played at most this many times in all, so unwinnable starts leave."""
    start_replay_capacity: int = 256
    """Lost starts kept for replay, the most recent ones (the queue follows the policy)."""
    target_update_interval: int = 100
    """Gradient updates between hard target refreshes (100 = every 50 episodes at the default
    2 updates per episode; the paper's "every 5 iterations" of 20 workers is 100 episodes).
    Refreshing every 10 episodes kept the greedy win rate oscillating."""
    grad_clip: float = 10.0
    """Gradient-norm clip (paper: 10)."""
    agent_hidden: int = 128
    """GRU width of the shared agent network (paper: 128)."""
    mixer_embed: int = 32
    """QMIX mixing-layer width (paper: 32)."""
    hypernet_hidden: int = 64
    """QMIX hypernetwork hidden width."""
    td_lambda: float = 0.3
    """λ of the TD(λ) targets (0: the paper's one-step targets; PyMARL2 uses 0.6). Against
    the easy bot in 30 minutes the test split read 0.89 / 0.885 / 0.86 on seeds 1-3 with
    0.3, 0.90 / 0.86 with 0.1, 0.86 / 0.875 with 0.6, and 0.77 on seed 1 with 0.9
    (docs/results.md, runs Z, AA, AD, AB, AC, P, R, W): short returns carry fewer of the
    ε-greedy actions' consequences into the targets, while λ > 0 still moves a win's +20
    back faster."""
    double_q: bool = True
    """Pick the next action with the online network, value it with the target network."""
    features: str = "relative"
    """Agent inputs: raw (the paper's: the observation as given) or relative (plus geometry
    derived from it, see trainers/features.py; learns much faster on the abstract 2 v 2)."""
    head: str = "points"
    """Q head: flat (the paper's: a linear output per action) or points (adds one small MLP
    that scores each action from its enemy's and point's features; needs 'relative'). On the
    easy bot it roughly doubles the greedy win rate after 500 episodes (bench_learning)."""
    augment: str = "enemies,field,allies"
    """Replay each sampled episode under a random symmetry of the task, so the learner sees
    every scene in all its equivalent forms: 'none', or a comma list of enemies (swap the
    enemy slots), field (turn the scene half a turn about the field's centre) and allies
    (swap the agents); see trainers/symmetry.py. Against the easy bot all three reach the
    0.85 plateau in about half the episodes (0.74-0.86 after 1,000 against 0.625-0.78
    without), but not higher (docs/results.md, runs P-R)."""
    last_action_input: bool = True
    """Give the agent network its one-hot last action."""
    agent_id_input: bool = True
    """Give the agent network its one-hot agent index."""
    buffer_size: int = 5000
    """Replay capacity in episodes."""
    batch_size: int = 32
    """Episodes per gradient update."""
    learning_starts: int = 64
    """Episodes in the buffer before learning begins."""
    train_every: int = 1
    """Asynchronous mode: episodes collected between training rounds."""
    updates_per_round: int = 2
    """Gradient updates per training round (per iteration in synchronous mode)."""
    # --- evaluation and records -------------------------------------------------------
    eval_every: int = 500
    """Training episodes between greedy evaluations (0 disables them until the end)."""
    eval_episodes: int = 50
    """Greedy episodes per evaluation, on held-out seeds."""
    final_eval_episodes: int = 200
    """Greedy episodes of the final evaluation at the end of the run (200: a win rate near
    0.9 is then known to about ±0.04)."""
    eval_seed: int = 1_000_000_000
    """First held-out seed; training episodes use seeds below it. Periodic evaluations
    (validation) use ``eval_seed + k``; the final evaluation (test) uses
    ``eval_seed + TEST_SEED_OFFSET + k``, so the figures reported at the end never come from
    the seeds that chose the best weights."""
    keep_best: bool = True
    """Keep the weights of the best periodic evaluation, write them to ``best.pt`` and
    evaluate them on the test seeds at the end beside the final weights (model selection
    on validation seeds, as is usual when reporting greedy win rates). Equal readings go to
    the later weights, which trained longer."""
    checkpoint_every: int = 1000
    """Training episodes between checkpoints (one is always written at the end)."""
    torch_threads: int = 1
    """Torch intra-op threads for the learner (workers always use 1)."""
    progress: bool = True
    """Show the live tqdm progress bar."""

    def __post_init__(self) -> None:
        _check_choice("alg", self.alg, sorted(ALGORITHMS))
        _check_choice("level", self.level, LEVELS)
        _check_choice("env", self.env, ENV_KINDS)
        _check_choice("servers", self.servers, SERVER_PLACEMENTS)
        parse_resources(self.worker_resources)
        parse_resources(self.server_resources)
        _check_choice("features", self.features, sorted(FEATURES))
        _check_choice("head", self.head, ("flat", "points"))
        if self.head == "points" and self.features not in POINT_FEATURES:
            raise ConfigError(
                f"head='points' needs features in {POINT_FEATURES}, got {self.features!r}"
            )
        try:
            parse_generators(self.augment)
        except ValueError as err:
            raise ConfigError(str(err)) from None
        for name in (
            "episodes",
            "batch_size",
            "buffer_size",
            "train_every",
            "updates_per_round",
            "target_update_interval",
            "agent_hidden",
            "mixer_embed",
            "hypernet_hidden",
            "eval_episodes",
            "torch_threads",
        ):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be ≥ 1, got {getattr(self, name)}")
        if self.workers < 0 or self.worker_cpus <= 0:
            raise ConfigError("workers must be ≥ 0 and worker_cpus > 0")
        if self.lr <= 0:
            raise ConfigError(f"lr must be > 0, got {self.lr}")
        if not 0.0 <= self.eps_end <= 1.0 or not 0.0 <= self.eps_start <= 1.0:
            raise ConfigError("eps_start and eps_end must lie in [0, 1]")
        if not 0.0 <= self.start_replay <= 1.0:
            raise ConfigError(f"start_replay must lie in [0, 1] (0 = off), got {self.start_replay}")
        if self.start_replay_plays < 2 or self.start_replay_capacity < 1:
            raise ConfigError(
                "start_replay_plays must be ≥ 2 (a first play and a replay) and "
                f"start_replay_capacity ≥ 1, got {self.start_replay_plays} and "
                f"{self.start_replay_capacity}"
            )

    @property
    def run_dir(self) -> Path:
        """The run directory, defaulting to runs/<alg>_<level>_s<seed>."""
        return Path(self.out or f"runs/{self.alg}_{self.level}_s{self.seed}")

    def n_workers(self) -> int:
        """Worker count: as configured, else one per core less one for the learner (≥ 2)."""
        return self.workers or max(2, (os.cpu_count() or 2) - 1)

    def to_dict(self) -> dict[str, Any]:
        """Plain values only (JSON- and ``torch.load(weights_only=True)``-safe)."""
        return dataclasses.asdict(self)


PRESETS: dict[str, dict[str, Any]] = {
    "paper": {
        "lr": 5e-4,
        "td_lambda": 0.0,
        "target_update_interval": 5,
        "features": "raw",
        "head": "flat",
        "augment": "none",
        "sync": True,
        "train_every": 1,
        "updates_per_round": 1,
        "eps_anneal_episodes": 2000,
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


def _check_choice(name: str, value: Any, valid: Iterable[Any]) -> None:
    valid = list(valid)
    if value not in valid:
        raise ConfigError(f"{name}={value!r} is not valid; valid: {', '.join(map(str, valid))}")


def field_docs() -> dict[str, str]:
    """Each field's docstring, read from the source (for ``--help-config``)."""
    tree = ast.parse(inspect.getsource(TrainConfig))
    body = tree.body[0].body  # type: ignore[attr-defined]
    docs: dict[str, str] = {}
    for node, after in itertools.pairwise(body):
        if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr):
            docs[node.target.id] = str(after.value.value)  # type: ignore[attr-defined]
    return docs


def _types() -> dict[str, Any]:
    return typing.get_type_hints(TrainConfig)


def _unknown(keys: Iterable[str], where: str) -> None:
    valid = [f.name for f in dataclasses.fields(TrainConfig)]
    bad = [k for k in keys if k not in valid]
    if bad:
        hints = {k: difflib.get_close_matches(k, valid, n=1) for k in bad}
        said = ", ".join(
            f"{k!r}" + (f" (did you mean {h[0]!r}?)" if h else "") for k, h in hints.items()
        )
        raise ConfigError(f"unknown config key(s) in {where}: {said}; valid: {', '.join(valid)}")


def _coerce(key: str, value: Any) -> Any:
    """Convert a file or command-line value to the field's type, or raise ConfigError."""
    kind = _types()[key]
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


def read_config_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Read a TOML or JSON file of config keys (flat, or under a ``[train]`` table)."""
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
    _unknown(data, str(p))
    return data


def parse_overrides(items: Iterable[str]) -> dict[str, str]:
    """``["key=value", ...]`` → ``{key: value}``; values are coerced later."""
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--set expects key=value, got {item!r}")
        out[key.strip()] = value
    _unknown(out, "--set")
    return out


def make_config(*layers: Mapping[str, Any], base: TrainConfig | None = None) -> TrainConfig:
    """Apply the layers in order over ``base`` (fresh defaults if none), checking each key."""
    values = (base or TrainConfig()).to_dict()
    for i, layer in enumerate(layers):
        _unknown(layer, f"layer {i}")
        values.update({k: _coerce(k, v) for k, v in layer.items()})
    return TrainConfig(**values)
