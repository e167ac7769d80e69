"""Task layer: action spaces, perception (candidate points, sight, LiDAR), observations,
planner and bots.

Importing the package points numba's kernel cache at a directory keyed by the sources
(:mod:`neuronsmae.server.sim.kernel_cache`) before any kernel module is imported.
"""

from __future__ import annotations

from neuronsmae.server.sim import kernel_cache

kernel_cache.configure()
