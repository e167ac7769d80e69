"""Experiments kept beside the main path: off by default, each with a measured reason.

An experiment lives here, with its settings in :class:`ExperimentalConfig`
(``TrainConfig.experimental``, keys ``experimental.<name>``), when it showed a measured gain
too small or too uncertain to change the defaults. The defaults keep the paper's algorithm,
so a default run measures what the paper measured; turning an experiment on changes nothing
else.

* :mod:`.starts`: replay of training starts the team did not win (``start_replay``).
"""

from __future__ import annotations

from neuronsmae.trainers.run.experimental.config import ExperimentalConfig
from neuronsmae.trainers.run.experimental.starts import StartReplay

__all__ = ["ExperimentalConfig", "StartReplay"]
