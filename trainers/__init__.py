"""Multi-agent Q-learning for NeuronsMAE: IQL, VDN and QMIX with Ray sampling workers.

Three sub-packages, each depending only on those before it:

* :mod:`.core` — the learning core, torch only: agent networks, mixers, the one Q-learner,
  replays, features, symmetries, acting, checkpoints;
* :mod:`.play` — playing episodes: rollout workers, opponents, evaluation,
  ``neuronsmae-match`` and ``neuronsmae-league``;
* :mod:`.run` — the training run: configuration, Ray sampling, the loop, records, plots,
  ``neuronsmae-train``.

Beside them: :mod:`.minimal`, the reference learner in one self-contained file; shared
configuration checks (:mod:`.checks`) and output-path checks (:mod:`.outputs`).

Names are imported lazily: ``neuronsmae-match`` between bots loads neither torch nor Ray.
The modules' paths before this layout (``neuronsmae.trainers.config``,
``neuronsmae.trainers.train``, ...) still import, with a ``DeprecationWarning`` naming the
new path; they will be removed in a later release.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from neuronsmae.trainers.play.evaluate import GreedyPolicy, evaluate_checkpoint, load_policy
    from neuronsmae.trainers.run.config import ConfigError, TrainConfig, make_config

_LAZY = {
    "ConfigError": "neuronsmae.trainers.run.config",
    "TrainConfig": "neuronsmae.trainers.run.config",
    "make_config": "neuronsmae.trainers.run.config",
    "GreedyPolicy": "neuronsmae.trainers.play.evaluate",
    "evaluate_checkpoint": "neuronsmae.trainers.play.evaluate",
    "load_policy": "neuronsmae.trainers.play.evaluate",
}

__all__ = [
    "ConfigError",
    "GreedyPolicy",
    "TrainConfig",
    "evaluate_checkpoint",
    "load_policy",
    "make_config",
]

MOVED = {
    **{name: f"core.{name}" for name in (
        "agent", "mixers", "learner", "buffer", "features", "symmetry", "point_order",
        "checkpoint",
    )},
    **{name: f"play.{name}" for name in (
        "rollout", "opponents", "evaluate", "policies", "match", "league", "pool", "task",
    )},
    **{name: f"run.{name}" for name in (
        "train", "sampler", "placement", "config", "config_groups", "contexts", "interrupt",
        "records", "cli", "competition", "plot", "experimental",
    )},
}  # fmt: skip
"""Module paths before the layout by job → their sub-package paths (deprecated aliases)."""


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old module path as the module at its new path, with a warning."""

    PREFIX = "neuronsmae.trainers."

    def find_spec(self, fullname: str, path: Any, target: Any = None) -> Any:
        head = fullname.removeprefix(self.PREFIX).partition(".")[0]
        if not fullname.startswith(self.PREFIX) or head not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: Any) -> Any:
        rest = spec.name.removeprefix(self.PREFIX)
        head, _, tail = rest.partition(".")
        new = self.PREFIX + MOVED[head] + (f".{tail}" if tail else "")
        warnings.warn(
            f"{spec.name} is now {new}; the old path will be removed in a later release",
            DeprecationWarning,
            stacklevel=2,
        )
        module = import_module(new)
        sys.modules[spec.name] = module
        return module

    def exec_module(self, module: Any) -> None:
        """Nothing to run: the module at the new path is already imported."""


if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
    sys.meta_path.append(_MovedFinder())


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'neuronsmae.trainers' has no attribute {name!r}")
