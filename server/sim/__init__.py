"""Simulation core: field constants, PyBullet world, chassis model, referee, spawns.

Importing the package points numba's kernel cache at a directory keyed by the sources
(:mod:`.kernel_cache`) before any kernel module is imported.
"""

from __future__ import annotations

from neuronsmae.server.sim import kernel_cache

kernel_cache.configure()
