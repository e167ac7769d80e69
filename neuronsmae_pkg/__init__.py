"""NeuronsMAE: a multi-robot reinforcement-learning environment on the RMUA arena.

The distribution maps the repository's top-level folders to sub-packages:
``server/`` → :mod:`neuronsmae.server`, ``client/`` → :mod:`neuronsmae.client`,
``protocol/`` → :mod:`neuronsmae.protocol`, ``trainers/`` → :mod:`neuronsmae.trainers`.
Dependencies point one way: trainers → client → protocol ← server.
"""

from __future__ import annotations

__version__ = "0.1.0"
