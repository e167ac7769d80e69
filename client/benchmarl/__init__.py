"""NeuronsMAE in BenchMARL: a task family, a command line, and a policy loader.

* :mod:`~neuronsmae.client.benchmarl.tasks`: :class:`NeuronsMAETask` (``COOP_ABSTRACT``, the
  paper's task, ``COOP_DISCRETE``, ``COOP_CONTINUOUS``, ``COOP_3V3``), BenchMARL tasks built on
  its ``Task`` / ``TaskClass`` API, each with YAML defaults in ``conf/task/neuronsmae/``.
* :mod:`~neuronsmae.client.benchmarl.run`: BenchMARL's Hydra command line with these tasks
  registered (``python -m neuronsmae.client.benchmarl.run algorithm=mappo
  task=neuronsmae/coop_continuous``).
The ``neuronsmae.policies`` loader that plays a trained BenchMARL experiment in
``neuronsmae-match`` and ``neuronsmae-league`` is the trainers'
(:mod:`neuronsmae.trainers.play.benchmarl`): it reads BenchMARL's pickles, which nothing on
the wire side may do.

BenchMARL comes with the ``interop`` extra. Importing this package imports nothing heavy; the
task names below import BenchMARL (and TorchRL) when first used.
"""

from __future__ import annotations

from typing import Any

__all__ = ["NeuronsMAEClass", "NeuronsMAETask", "TaskSettings"]


def __getattr__(name: str) -> Any:
    if name in __all__:
        from neuronsmae.client.benchmarl import tasks

        return getattr(tasks, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
