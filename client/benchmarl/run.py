"""BenchMARL's command line with the NeuronsMAE tasks::

    python -m neuronsmae.client.benchmarl.run algorithm=mappo task=neuronsmae/coop_continuous
    python -m neuronsmae.client.benchmarl.run algorithm=qmix task=neuronsmae/coop_abstract \\
        task.level=middle task.options.episode_steps=500 experiment.max_n_frames=100000

BenchMARL's own ``benchmarl/run.py`` knows only the tasks listed in its source: its task
registry (``benchmarl.environments.task_config_registry``) is filled from a fixed list, and
its Hydra search path is its own ``conf`` folder. This module registers the NeuronsMAE tasks
(:mod:`neuronsmae.client.benchmarl.tasks`), adds this package's ``conf`` folder to Hydra's
search path and runs BenchMARL's ``hydra_experiment`` with the arguments given, so every
override of BenchMARL's command line works as documented there.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence


def main(argv: Sequence[str] | None = None) -> None:
    """Run one BenchMARL experiment from Hydra overrides (``argv``; default: the command
    line's)."""
    from benchmarl.run import hydra_experiment

    from neuronsmae.client.benchmarl.tasks import CONF

    args = list(sys.argv[1:] if argv is None else argv)
    if not any(a.startswith("hydra.searchpath=") for a in args):
        args.append(f"hydra.searchpath=[file://{CONF}]")
    sys.argv = [sys.argv[0], *args]
    hydra_experiment()


if __name__ == "__main__":
    main()
